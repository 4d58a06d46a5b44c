// The narrow bridge between the session store and the back-end: the store knows nothing of
// MultiSessionBackend (it keeps sessions, keyframes, loops and maps in its own store ids), and
// the back-end knows nothing of SQLite. These two functions translate one into the other, with
// the remapping of store ids to live ids (cf. cartographer's LoadState returning its remapping).
// Only the SessionManager (session_manager.h) and the store's tools call them.
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "uw_multislam/core/backend/backend.h"
#include "uw_multislam/core/loops/loop_detector.h"
#include "uw_multislam/core/store/session_store.h"

namespace uw_multislam {
namespace core {

/// Everything a store holds, put into a back-end and a loop detector (offline_slam, the
/// session manager's reload). Sessions are restored in store order as finished sessions (the
/// back-end's ids follow the order); a session without keyframes is skipped.
struct RestoredStore {
  std::vector<std::int64_t> session_ids;            // back-end session -> store session id
  std::vector<std::int64_t> loop_ids;               // back-end loop -> store loop id
  std::vector<std::vector<int>> frame_of_keyframe;  // per restored session
  std::vector<StoredLoop> loops;                    // the stored loops, in back-end loop order
  int keyframes = 0;
  /// What was repaired on the way, one line each (for the log): a map whose stored motions were
  /// damaged (not finite, a covariance checkCovariance refuses) is rebuilt from its sessions'
  /// odometry and links and optimised again at the next flush; a map with a damaged link, or
  /// naming a session the store does not hold, leaves its sessions unjoined.
  std::vector<std::string> notes;
};

/// Restores every stored session, loop, map and split pair into an empty back-end and, when
/// `detector` is not null, every keyframe into it (the cameras are appended to `cameras`, which
/// must outlive the detector). Throws StoreError or std::invalid_argument.
RestoredStore restoreStore(const SessionStore& store, MultiSessionBackend* backend, LoopDetector* detector,
                           std::vector<std::unique_ptr<CameraIntrinsics>>* cameras);

/// The back-end's maps and loop states in store ids (session_ids / loop_ids map back-end ids to
/// store ids), then SessionStore::saveMaps.
void saveBackendMaps(SessionStore* store, const MultiSessionBackend& backend,
                     const std::vector<std::int64_t>& session_ids, const std::vector<std::int64_t>& loop_ids);

}  // namespace core
}  // namespace uw_multislam
