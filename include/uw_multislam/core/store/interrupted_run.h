// A run killed before its session ended (kill -9, power cut) leaves that session `recording` in
// the store, with every keyframe written before the kill. Running the same folder
// again must not silently duplicate it, nor refuse it as if it were complete: the caller chooses
// explicitly (offline_slam --interrupted discard|finish).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/store/session_store.h"

namespace uw_multislam {
namespace core {

/// Whether every keyframe (frame index, stamp) is a frame of `frames`: same index, stamp within
/// 1 us. What "a folder already in the store" means (SessionManager::storedSessionsOf too).
bool keyframesAreFramesOf(const std::vector<int>& frame_indexes, const std::vector<double>& stamps,
                          const std::vector<FrameRecord>& frames);

/// An interrupted run over one folder: its `recording` session and the finished pieces of the
/// same run before it (a tracking loss splits a folder into pieces, stored one after the other,
/// each ending before the next one's first frame).
struct InterruptedRun {
  std::vector<std::int64_t> store_ids;  // in store order; the last is the recording session
  std::vector<int> ids;                 // the session manager's ids: the store ids
  std::string name;                     // the recording session's name
  int keyframes = 0;                    // in all of them
  double last_stamp_s = 0.0;            // the recording session's last keyframe
};

/// The interrupted runs of `frames` in `store` (none: an empty vector).
std::vector<InterruptedRun> findInterruptedRuns(const SessionStore& store, const std::vector<FrameRecord>& frames);

enum class InterruptedChoice { kDiscard, kFinish };
/// kDiscard: deletes the run's sessions (SessionStore::deleteSessions, one transaction), so the
/// folder can be processed again. kFinish: marks the recording session finished at its last
/// keyframe's stamp; the run's keyframes stay as stored. Throws StoreError.
void resolveInterruptedRun(SessionStore* store, const InterruptedRun& run, InterruptedChoice choice);

}  // namespace core
}  // namespace uw_multislam
