#include "uw_multislam/core/frontend/pair_motion.h"

namespace uw_multislam {
namespace core {

PairMotion estimatePairMotion(const View& a, const View& b, const MatchOptions& matching, const RansacOptions& ransac,
                              StageTimes* times, const MotionPrior* prior) {
  PairMotion out;
  std::vector<FeatureMatch> matches;
  {
    ScopedStage s(times, "match");
    matches = matchDescriptors(a.features->descriptors, b.features->descriptors, matching);
  }
  out.matches = static_cast<int>(matches.size());
  std::vector<Eigen::Vector2d> pa, pb;
  pa.reserve(matches.size());
  pb.reserve(matches.size());
  for (const auto& m : matches) {
    pa.push_back(pixelToMetres(a.features->keypoints[m.a].pt, *a.camera, a.altitude_m));
    pb.push_back(pixelToMetres(b.features->keypoints[m.b].pt, *b.camera, b.altitude_m));
  }
  ScopedStage s(times, "ransac");
  // Pixel thresholds in metres at the scale of the second view (the newer one).
  const double metres_per_px = b.altitude_m / (0.5 * (b.camera->fx + b.camera->fy));
  out.ransac = estimateRigidRansac(pa, pb, metres_per_px, ransac, prior);
  out.correspondences = std::move(matches);
  return out;
}

}  // namespace core
}  // namespace uw_multislam
