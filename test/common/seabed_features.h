// The rendered seabed's frames as the loop tests need them: enhanced, then the extractor's
// features (default options), optionally dimmed by `gain` (another day's light).
#pragma once

#include <opencv2/core.hpp>

#include "rendered_seabed.h"
#include "uw_multislam/core/frontend/odometry.h"

namespace uw_multislam {
namespace testing_util {

class SeabedFeaturesTest : public RenderedSeabedTest {
 protected:
  core::FrameFeatures features(const core::Pose2& p, double alt, double gain = 1.0) const {
    cv::Mat img = render(p, alt);
    img.convertTo(img, -1, gain, 0.0);
    core::FeatureImageEnhancer enhancer(core::OdometryOptions().enhancement);
    return core::FeatureExtractor(core::FeatureOptions()).extract(enhancer.enhance(img));
  }
};

}  // namespace testing_util
}  // namespace uw_multislam
