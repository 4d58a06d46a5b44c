// Survey missions for the generator: the path of a bottom-looking camera over the seabed.
//
// A pattern is laid out in a local frame (start at the origin, travelling along +x, turning
// towards +y), then turned by `heading_rad` and moved to `start_m` in the world. Frames are
// taken every `speed_m_s * frame_period_s` metres of path. The camera's image x axis points
// `camera_yaw_offset_rad` away from the direction of travel, and the vehicle's heading wobbles
// slowly (`wobble_yaw_rad`) as a real AUV's does.
#pragma once

#include <Eigen/Core>

#include <string>
#include <vector>

#include "uw_multislam/core/geometry/se2.h"

namespace uw_multislam {
namespace core {

enum class MissionPattern { kLawnmower, kOutAndBack, kLoop, kFigureEight };

/// "lawnmower", "out_and_back", "loop", "figure_eight".
std::string patternName(MissionPattern p);
/// Parses a pattern name; returns false for an unknown one.
bool parsePattern(const std::string& name, MissionPattern* out);

struct MissionSpec {
  MissionPattern pattern = MissionPattern::kLawnmower;
  /// World position (m) of the first frame and direction of travel at the start (rad).
  Eigen::Vector2d start_m = Eigen::Vector2d(4.0, 4.0);
  double heading_rad = 0.0;
  /// lawnmower: leg length; out_and_back: one-way length; loop: long side of the rounded
  /// rectangle; figure_eight: overall length.
  double length_m = 12.0;
  /// lawnmower: total width covered by the legs; loop: short side; figure_eight: overall width.
  double width_m = 6.0;
  /// lawnmower: distance between legs; out_and_back: lateral offset of the way back.
  double leg_spacing_m = 1.4;
  /// loop and figure_eight: how many laps (fractions allowed; > 1 revisits the start).
  double laps = 1.15;
  double speed_m_s = 0.5;
  double frame_period_s = 1.0;
  double camera_yaw_offset_rad = 0.0;
  double altitude_m = 2.5;
  /// Sinusoidal altitude change along the path: amplitude and period in metres of path.
  double altitude_amplitude_m = 0.0;
  double altitude_period_m = 25.0;
  /// Slow heading oscillation of the vehicle: amplitude (rad) and period (m of path).
  double wobble_yaw_rad = 0.03;
  double wobble_period_m = 7.0;
  /// Time of the first frame (s); frames follow every frame_period_s.
  double start_time_s = 0.0;

  /// Empty when usable, else a sentence naming the bad value.
  std::string validate() const;
};

/// One frame of a planned mission, in the world frame.
struct MissionFrame {
  Pose2 pose;         // pose of the principal point's ground point, image axes
  double altitude_m;  // true altitude above the seabed
  double stamp_s;
  double path_m;                 // distance travelled since the first frame
  Eigen::Vector2d velocity_m_s;  // world velocity (for motion blur)
};

/// Plans the frames of a mission. Throws std::invalid_argument with validate()'s reason.
std::vector<MissionFrame> planMission(const MissionSpec& spec);

}  // namespace core
}  // namespace uw_multislam
