// A textured procedural seabed (12 x 8 m, no featureless sand) built once per test process, and
// the 320 x 240 camera the tests fly over it.
#pragma once

#include <gtest/gtest.h>

#include "uw_multislam/sim/seabed_world.h"

namespace uw_multislam {
namespace testing_util {

class RenderedSeabedTest : public ::testing::Test {
 protected:
  static const core::SeabedWorld& world() {
    static const core::SeabedWorld w = [] {
      core::ProceduralSeabedOptions o;
      o.width_m = 12;
      o.height_m = 8;
      o.metres_per_px = 0.006;
      o.featureless_fraction = 0.0;
      return core::SeabedWorld::procedural(o);
    }();
    return w;
  }
  cv::Mat render(const core::Pose2& p, double altitude_m) const { return world().render(p, altitude_m, camera_); }

  const core::CameraIntrinsics camera_{320, 240, 300.0, 300.0, 159.5, 119.5};
};

}  // namespace testing_util
}  // namespace uw_multislam
