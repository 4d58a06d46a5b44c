// Global loops between stored sessions: loops are also searched among reloaded sessions, so that
// two stored sessions can be joined without a live one (and the sessions of merged stores).
//
// The sessions come in groups; the keyframes of group g are queried against the sessions of
// groups 0..g-1 only, as if group g had been recorded after them: the stored hash of each keyframe
// (LoopDetector::globalCandidates, best_k candidates among the earlier groups' keyframes), each
// candidate verified by RANSAC on the stored features (paged: read from the store through the
// detector's LRU cache), and each accepted loop that the manager does not hold yet handed to
// SessionManager::addLoop in keyframe order. The manager's join policy decides the joins as it does
// live. Loops within a group are not searched (they were found when it was recorded).
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "uw_multislam/core/session/session_manager.h"
#include "uw_multislam/core/session/slam_config.h"

namespace uw_multislam {
namespace core {

struct StoredLoopSearch {
  int queries = 0, candidates = 0, found = 0, accepted = 0, refused = 0, duplicates = 0;
};

/// See the file comment. Every session named must be a stored session of `manager` (restored from
/// its store). `config` gives the loop verification (the hash settings must be the manager's).
/// Throws std::invalid_argument (a session named twice or not stored) or StoreError (a stored
/// keyframe that cannot be read: nothing is handed to the manager after it).
StoredLoopSearch searchStoredLoops(SessionManager* manager, const SlamConfig& config,
                                   const std::vector<std::vector<int>>& groups,
                                   const std::function<void(const std::string&)>& log = {});

/// The back-end's detect_loops service: searchStoredLoops over `sessions` as groups of one, in the
/// order given (each searched against those before it). Checked first, nothing changed on refusal:
/// INVALID_ARGUMENT for fewer than two sessions or one named twice, NOT_FOUND for an unknown id,
/// FAILED_PRECONDITION without a store or for a session not restored from it (recorded in this
/// run: its loops were searched live). DATA_LOSS when a stored keyframe cannot be read: the loops
/// accepted before it stay (counted in `out`).
Status detectStoredLoops(SessionManager* manager, const SlamConfig& config, const std::vector<int>& sessions,
                         StoredLoopSearch* out, const std::function<void(const std::string&)>& log = {});

/// add_link's "find it" form: the pose of keyframe b in keyframe a's frame measured by RANSAC
/// between the two keyframes' stored features (the loop detector's matching and verification,
/// `config`), into `link` (z and inliers; the ids are the caller's). Both sessions must be restored
/// from the store (a session recorded in this run keeps its features in the loop detector node:
/// give the pose). Nothing changes: INVALID_ARGUMENT (a negative keyframe id, a keyframe linked to
/// itself), NOT_FOUND (an unknown session or keyframe), FAILED_PRECONDITION (no store, a session
/// of this run, localisation mode, or no motion verified: fewer inliers than the loops'
/// min_inliers, said with the counts), DATA_LOSS (the stored features cannot be read).
Status findStoredLink(const SessionQueries& manager, const SlamConfig& config, Loop* link);

/// The operator's link (the back-end's add_link, offline_slam --add-link), checked and, when
/// `measure`, measured from the stored features (findStoredLink: z and inliers), nothing changed:
/// OK when SessionManager::addLink would take it; the codes of findStoredLink, or of addLink's
/// checks (SessionManager::checkLink) when the pose is given. A caller that checks several links
/// before adding any (offline_slam) calls this first, then addOperatorLink. `given_yaw` is the
/// pose's yaw as the caller received it (rad; Pose2 wraps it): a given pose's yaw outside
/// [-pi, pi] is refused (INVALID_ARGUMENT), and so are inliers above the keyframes' feature
/// count (SessionQueries::checkLink).
Status checkOperatorLink(const SessionQueries& manager, const SlamConfig& config, bool measure, Loop* link,
                         double given_yaw);
/// checkOperatorLink, then SessionManager::addLink: the link is a loop like a detector's (stored,
/// optimised, counted towards joins). *link holds the measured pose and inliers.
Status addOperatorLink(SessionManager* manager, const SlamConfig& config, bool measure, Loop* link, double given_yaw);

}  // namespace core
}  // namespace uw_multislam
