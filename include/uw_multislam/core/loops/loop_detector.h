// Loop detection (paper 000 §6 and §7).
//
// Local loops (4)(5): keyframes of the same session whose estimated position lies within
// radius δ of the new keyframe's, leaving out the `exclude_recent` previous keyframes; δ may be
// widened by the position uncertainty accumulated between the two keyframes (k-sigma of the
// summed motion covariances). The nearest `max_candidates` are verified by RANSAC.
//
// Global loops (8)(9): the new keyframe's HALOC hash is compared by L1 distance with the
// hashes of every keyframe of the other sessions; the best `best_k` (and, if set, those within
// `max_l1`) are verified by RANSAC.
//
// Candidates from the map's own geometry (global.follow_loops): once a global loop puts the new
// keyframe in another session's frame, the other session's keyframes within the local radius of
// that place are verified too (a revisit overlaps several keyframes, the hash ranks only some of
// them high); and the session's next keyframes are predicted there by their odometry from that
// anchor (the local search's radius, widened by the odometry's uncertainty since the anchor; the
// anchor is dropped once the radius reaches max_radius_m), so a revisit is followed keyframe by
// keyframe where the hash misses it. Such a candidate is accepted only when its measured pose puts
// the new keyframe within that radius of the prediction. Only keyframes added live (addKeyframe)
// carry the pose in their session's frame this needs; stored keyframes are found by hash alone.
//
// A loop is accepted when RANSAC succeeds with at least `min_inliers` inliers; its measurement
// is the motion of the new keyframe in the old one's frame with the RANSAC covariance.
//
// Every keyframe's features are kept (descriptors as 8 bits: OpenCV's SIFT values are integers
// in 0..255) for later verification: about 66 kB per keyframe with n = 500. Except with paging:
// a keyframe of a stored session added by addPagedKeyframe keeps only its hash and
// ids in RAM (about 0.5 kB); its features are read from the session store when it is a
// candidate, through an LRU cache of `feature_cache_mb` (feature_cache.h). The search is the same
// exact one, and so are the loops found (tested).
#pragma once

#include <cstdint>
#include <limits>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "uw_multislam/core/frontend/pair_motion.h"
#include "uw_multislam/core/geometry/trajectory.h"
#include "uw_multislam/core/loops/feature_cache.h"
#include "uw_multislam/core/loops/haloc.h"

namespace uw_multislam {
namespace core {

struct LocalLoopOptions {
  bool enabled = true;
  double radius_m = 1.5;        // δ of (4)
  double sigma_widening = 2.0;  // δ += k * sigma of the relative position (0 = off)...
  double max_radius_m = 5.0;    // ...up to this
  int exclude_recent = 2;       // the previous keyframes left out (they are odometry's)
  /// Nearest candidates verified per keyframe: the global search's budget (best_k). A revisit
  /// overlaps several earlier keyframes (a parallel track line, a vehicle hovering at a turn), and
  /// each of them is a loop a person sees; 3 verified only the nearest (real survey: 12 of 148
  /// ground-truth pairs never proposed).
  int max_candidates = 10;
  /// RANSAC inliers to accept a loop: the odometry's N_min (ransac.min_inliers). The paper's 25 cut
  /// true revisits with 20-24 inliers (real survey: 3 of 148 ground-truth pairs) and protected
  /// nothing: with the verification's mutual matches and ratio, frames that do not overlap kept at
  /// most 6 inliers (1284 such real pairs).
  int min_inliers = 20;

  std::string validate() const;
};

struct GlobalLoopOptions {
  bool enabled = true;
  // Candidates verified per keyframe (the paper used 5). With the sorted-DCT hash, 10 gives an
  // inter-session recall of 0.73 on the demo survey and 1.0 on flights/acfr_test4 (5: 0.45 and
  // 0.94), precision 1.0, for about 7-12 ms of verification per keyframe.
  int best_k = 10;
  double max_l1 = 0.0;  // δ' of (8); 0 = no threshold, best_k only
  /// kSortedDct (default, see haloc.h: it ranks true revisits far better) or the paper's kHaloc.
  HashMode hash_mode = HashMode::kSortedDct;
  int min_inliers = 20;  // as the local loops'
  /// Verify around where an accepted global loop puts the keyframe in the other session, and
  /// follow the revisit with the odometry (see the header comment).
  bool follow_loops = true;
  std::uint64_t projection_seed = 20231122;  // the HALOC vectors; stored with the maps

  std::string validate() const;
};

struct LoopOptions {
  LocalLoopOptions local;
  GlobalLoopOptions global;
  /// Lowe's ratio of the verification's SIFT matching (mutual matches kept, as the odometry's
  /// matching.mutual says), in place of the odometry's. Looser than the odometry's 0.8: two views
  /// of a revisit overlap by half or less, and on low-contrast seabed the second-nearest
  /// descriptor is close to the nearest, so 0.8 dropped most true matches (real survey: 20 of 148
  /// ground-truth pairs under 25 inliers at 0.8, 5 at 0.9), while pairs that do not overlap kept
  /// at most 6 inliers at 0.9, far below min_inliers. Binary (ORB) matching keeps
  /// matching.binary_ratio.
  double ratio = 0.9;
  /// Paging: the byte budget (MiB) of the cache of stored keyframes' features read from the
  /// session store for verification (about 78 kB each at n = 500: 64 MiB keeps about 850).
  double feature_cache_mb = 64.0;
  /// In the nodelets (paging): the back-end hands stored keyframes to the loop
  /// detectors with their hashes only, and a loop detector reads a candidate's features from the
  /// back-end's store (service keyframe_features) through that cache. false: every stored
  /// keyframe's features are sent and kept in the loop detector's RAM (about 70 kB each).
  /// offline_slam --db always pages.
  bool page_stored = true;
  /// With page_stored, in the loop detector nodelet: a live keyframe this many keyframes behind
  /// its session's newest is paged out too, once the back-end's store has it (asked with
  /// keyframe_features check_only; without a store nothing is paged). The local search still
  /// finds it (by pose); its features are read back when it is a candidate. 0: never.
  int page_live_after = 50;
  std::string validate() const;
};

struct Loop {
  enum class Kind { kLocal, kGlobal };
  Kind kind = Kind::kLocal;
  int session_a = 0, keyframe_a = 0, frame_a = 0;  // the stored (older) keyframe
  int session_b = 0, keyframe_b = 0, frame_b = 0;  // the new keyframe
  UncertainPose2 z;                                // pose of b in a's frame
  int inliers = 0;
  float hash_l1 = 0.0f;        // global loops: the hash distance
  bool nav_placement = false;  // not a visual loop: the nav's placement of a session (session_manager.h)
};

struct LoopStats {
  int keyframes = 0;
  int local_candidates = 0, local_accepted = 0;
  int global_candidates = 0, global_accepted = 0;      // hash and followed candidates together
  int followed_candidates = 0, followed_accepted = 0;  // of them, from the map's geometry (follow_loops)
  int feature_read_failures = 0;                       // paged candidates skipped: their features could not be read
};

class LoopDetector {
 public:
  /// `num_features` is the n of the hashes (the extractor's). Throws std::invalid_argument.
  LoopDetector(const LoopOptions& options, const MatchOptions& matching, const RansacOptions& ransac, int num_features);

  /// Stores a new keyframe and returns the loops it closes. `trajectory` is the current estimate
  /// of its session (keyframe ids index its poses); `camera` must outlive the detector.
  /// `hash`: the keyframe's hash when it was computed upstream (each keyframe is hashed once:
  /// core::Pipeline and the odometry nodelet hash it, see session_manager.h); nullptr or empty:
  /// computed here.
  std::vector<Loop> addKeyframe(int session, int keyframe, int frame_index, double altitude_m,
                                const CameraIntrinsics* camera, const FrameFeatures& features,
                                const Trajectory& trajectory, const Eigen::VectorXf* hash = nullptr);

  /// Stores a keyframe of a stored session (session store) without searching for loops, so that
  /// later keyframes find loops against it. `hash` is the one stored with it (same hash mode,
  /// seed and n as this detector: the caller checks); descriptors CV_8U or CV_32F. Throws
  /// std::invalid_argument on a bad hash size or a keyframe stored twice.
  void addStoredKeyframe(int session, int keyframe, int frame_index, double altitude_m, const CameraIntrinsics* camera,
                         const FrameFeatures& features, const Eigen::VectorXf& hash);
  /// Paging: where the features of keyframes added by addPagedKeyframe are read from (the
  /// session store, by session and keyframe id), through an LRU cache of
  /// options.feature_cache_mb. Call before addPagedKeyframe; a second call replaces the cache.
  void setFeatureLoader(FeatureCache::Loader loader);
  /// A keyframe of a stored session that keeps only its hash and ids in RAM; its features are
  /// read with the loader when it is a candidate (a failed read: the candidate is skipped,
  /// counted in stats().feature_read_failures, the message in lastReadError()). Throws
  /// std::invalid_argument without a loader, on a bad hash size or a keyframe stored twice.
  void addPagedKeyframe(int session, int keyframe, int frame_index, double altitude_m, const CameraIntrinsics* camera,
                        const Eigen::VectorXf& hash);
  /// Another vehicle's keyframe (a fleet exchanging hashes), of which only the hash crossed the link: the
  /// global search runs for it against every other session held (this vehicle's included), and
  /// only when there are candidates are its features read with the loader (asked of that
  /// vehicle) to verify them; it is then held paged, so this vehicle's later keyframes find it
  /// too (searching both ways, each vehicle finds every loop between the two). Returns the
  /// loops, a = the candidate, b = this keyframe. A failed read is counted as for paged
  /// keyframes (no loop). Throws std::invalid_argument as addPagedKeyframe.
  std::vector<Loop> addForeignKeyframe(int session, int keyframe, int frame_index, double altitude_m,
                                       const CameraIntrinsics* camera, const Eigen::VectorXf& hash);
  /// Pages out a keyframe held with its features (a live one, once it is in the session store):
  /// its features are dropped and read with the loader when it is a candidate, as a stored
  /// keyframe's. False (nothing changed) without a loader, for a keyframe not held or already
  /// paged. The loops found do not change as long as the loader returns what addKeyframe was
  /// given (descriptors as CV_8U, as kept).
  bool pageOut(int session, int keyframe);
  /// Forgets every keyframe of `session` (unload_session): its hashes, features and ids, so it is
  /// no candidate any more and its memory is freed; it may be added again later. Returns how
  /// many keyframes it held. O(size()).
  int dropSession(int session);
  /// The cache of paged keyframes' features (nullptr before setFeatureLoader).
  const FeatureCache* featureCache() const { return cache_.get(); }
  const std::string& lastReadError() const { return last_read_error_; }

  /// The hash of the keyframe last given to addKeyframe (what the session store keeps).
  const Eigen::VectorXf& lastHash() const { return last_hash_; }

  /// The global search of addKeyframe alone: the best_k stored keyframes of sessions other than
  /// `session` nearest to `hash` (and within max_l1), nearest first. The reference stays valid
  /// until the next call (its storage is reused).
  const std::vector<HashCandidate>& globalCandidates(const Eigen::VectorXf& hash, int session);
  /// The verification of addKeyframe for one global candidate (RANSAC (9) between the stored
  /// keyframe and `now`): true and `loop` filled (kind global, keyframe a) when accepted.
  bool verifyCandidate(const HashCandidate& candidate, const View& now, Loop* loop);

  const ImageHasher& hasher() const { return hasher_; }
  const LoopStats& stats() const { return stats_; }
  const StageTimes& times() const { return times_; }
  std::size_t size() const { return keyframes_.size(); }
  /// Whether keyframe `keyframe` of `session` is held (live, stored or paged).
  bool has(int session, int keyframe) const {
    return session >= 0 && keyframe >= 0 && session < static_cast<int>(by_session_.size()) &&
           keyframe < static_cast<int>(by_session_[session].size()) && by_session_[session][keyframe] >= 0;
  }

 private:
  struct Stored {
    int session, keyframe, frame_index;
    double altitude_m;
    const CameraIntrinsics* camera;
    FrameFeatures features;  // keypoint positions; descriptors as CV_8U (empty when paged)
    bool paged;              // features read through cache_ when needed
    bool has_pose = false;   // added live: `pose` is its pose in its session's frame then
    Pose2 pose;
  };
  // Where keyframe `keyframe` of a session was put in another session's frame by a global loop.
  struct Anchor {
    int keyframe = -1;
    Pose2 in_other;
  };
  /// follow_loops: the candidates of the other sessions around the new keyframe's predicted
  /// places (from this keyframe's accepted global loops, else from the anchors), verified into
  /// `loops`; the anchors updated.
  void followLoops(int session, int keyframe, const Trajectory& trajectory, const View& now, std::vector<Loop>* loops);
  bool verify(const Stored& old, const View& now, Loop* loop);
  /// The global search (into scratch_) when it is on and something is held; true: candidates.
  bool queryGlobal(const Eigen::VectorXf& hash, int session);
  /// Verifies scratch_'s candidates against `now`, appending the accepted loops.
  void verifyGlobal(const View& now, std::vector<Loop>* loops);
  /// The new keyframe as every loop's b, counted as accepted.
  void nameNewKeyframe(std::vector<Loop>* loops, int session, int keyframe, int frame_index);
  void checkStored(int session, int keyframe, const Eigen::VectorXf& hash) const;
  void store(int session, int keyframe, int frame_index, double altitude_m, const CameraIntrinsics* camera,
             const FrameFeatures* features, const Eigen::VectorXf& hash);
  std::vector<int> localCandidates(int session, int keyframe, const Trajectory& trajectory) const;

  LoopOptions options_;
  MatchOptions matching_;
  RansacOptions ransac_;
  ImageHasher hasher_;
  HashStore hashes_;  // entry i <-> keyframes_[i]; range set by the hash mode
  std::vector<Stored> keyframes_;
  std::vector<std::vector<int>> by_session_;       // [session][keyframe] -> index into keyframes_
  std::map<std::pair<int, int>, Anchor> anchors_;  // (session, other session) -> its latest anchor there
  std::vector<HashCandidate> scratch_;
  Eigen::VectorXf last_hash_;
  std::unique_ptr<FeatureCache> cache_;
  std::string last_read_error_;
  LoopStats stats_;
  StageTimes times_;
};

std::string loopKindName(Loop::Kind k);
/// The matching options of loop verification: the odometry's with the loops' ratio.
MatchOptions loopMatching(const MatchOptions& odometry, const LoopOptions& loops);

}  // namespace core
}  // namespace uw_multislam
