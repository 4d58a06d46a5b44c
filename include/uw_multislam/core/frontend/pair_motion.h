// Motion between two views from their features: match descriptors, scale both point sets to
// metres with each view's altitude and camera, RANSAC (paper 000 Algorithm 1). Used by the
// odometry (frame to keyframe) and by the loop detectors (verification, (5) and (9)).
#pragma once

#include "uw_multislam/core/common/stage_timer.h"
#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/frontend/features.h"
#include "uw_multislam/core/frontend/matching.h"
#include "uw_multislam/core/frontend/rigid_ransac.h"

namespace uw_multislam {
namespace core {

/// One view: its features, altitude and camera.
struct View {
  const FrameFeatures* features;
  double altitude_m;
  const CameraIntrinsics* camera;
};

struct PairMotion {
  RansacResult ransac;  // motion of b in a's frame (X_b^a) when ransac.success
  int matches = 0;
  std::vector<FeatureMatch> correspondences;  // the matches RANSAC ran on (ransac.inliers index them)
};

/// `times` (optional) receives the "match" and "ransac" stages.
/// `prior` (optional): RANSAC's hypotheses are gated by it (rigid_ransac.h).
PairMotion estimatePairMotion(const View& a, const View& b, const MatchOptions& matching, const RansacOptions& ransac,
                              StageTimes* times = nullptr, const MotionPrior* prior = nullptr);

}  // namespace core
}  // namespace uw_multislam
