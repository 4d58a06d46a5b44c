#include "uw_multislam/sim/survey_mission.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace uw_multislam {
namespace core {

namespace {

using Polyline = std::vector<Eigen::Vector2d>;
constexpr double kStep = 0.01;  // spacing of the dense path (m)

void lineTo(Polyline& p, const Eigen::Vector2d& to) {
  const Eigen::Vector2d from = p.back();
  const int n = std::max(1, static_cast<int>(std::ceil((to - from).norm() / kStep)));
  for (int i = 1; i <= n; ++i) p.push_back(from + (to - from) * (static_cast<double>(i) / n));
}

// Arc around `centre` from the current point, sweeping `sweep` radians (positive = towards +y
// when travelling along +x, i.e. clockwise on screen with y down).
void arc(Polyline& p, const Eigen::Vector2d& centre, double sweep) {
  const Eigen::Vector2d r0 = p.back() - centre;
  const double radius = r0.norm(), a0 = std::atan2(r0.y(), r0.x());
  const int n = std::max(1, static_cast<int>(std::ceil(std::abs(sweep) * radius / kStep)));
  for (int i = 1; i <= n; ++i) {
    const double a = a0 + sweep * i / n;
    p.push_back(centre + radius * Eigen::Vector2d(std::cos(a), std::sin(a)));
  }
}

Polyline lawnmower(const MissionSpec& s) {
  const int legs = std::max(1, static_cast<int>(std::floor(s.width_m / s.leg_spacing_m + 1e-9)) + 1);
  const double r = s.leg_spacing_m / 2;
  Polyline p{Eigen::Vector2d::Zero()};
  for (int i = 0; i < legs; ++i) {
    const double y = i * s.leg_spacing_m;
    const bool forward = i % 2 == 0;
    lineTo(p, Eigen::Vector2d(forward ? s.length_m : 0.0, y));
    if (i + 1 < legs) arc(p, Eigen::Vector2d(forward ? s.length_m : 0.0, y + r), forward ? M_PI : -M_PI);
  }
  return p;
}

Polyline outAndBack(const MissionSpec& s) {
  const double r = s.leg_spacing_m / 2;
  Polyline p{Eigen::Vector2d::Zero()};
  lineTo(p, Eigen::Vector2d(s.length_m, 0.0));
  arc(p, Eigen::Vector2d(s.length_m, r), M_PI);
  lineTo(p, Eigen::Vector2d(0.0, 2 * r));
  return p;
}

Polyline roundedRectangle(const MissionSpec& s) {
  const double l = s.length_m, w = s.width_m, r = std::min(l, w) / 4;
  // One lap starting at the middle of the first long side, then repeated for `laps`.
  Polyline lap{Eigen::Vector2d::Zero()};
  lineTo(lap, Eigen::Vector2d(l / 2 - r, 0));
  arc(lap, Eigen::Vector2d(l / 2 - r, r), M_PI / 2);
  lineTo(lap, Eigen::Vector2d(l / 2, w - r));
  arc(lap, Eigen::Vector2d(l / 2 - r, w - r), M_PI / 2);
  lineTo(lap, Eigen::Vector2d(-l / 2 + r, w));
  arc(lap, Eigen::Vector2d(-l / 2 + r, w - r), M_PI / 2);
  lineTo(lap, Eigen::Vector2d(-l / 2, r));
  arc(lap, Eigen::Vector2d(-l / 2 + r, r), M_PI / 2);
  lineTo(lap, Eigen::Vector2d(0, 0));
  return lap;
}

Polyline figureEight(const MissionSpec& s) {
  // Lemniscate of Gerono, crossing itself at the start: x = L/2 sin t, y = W/2 sin t cos t.
  Polyline lap;
  const int n = static_cast<int>(std::ceil(2 * (s.length_m + s.width_m) * 2 / kStep));
  for (int i = 0; i <= n; ++i) {
    const double t = 2 * M_PI * i / n;
    lap.emplace_back(s.length_m / 2 * std::sin(t), s.width_m / 2 * std::sin(t) * std::cos(t));
  }
  return lap;
}

// Repeats a closed lap `laps` times (the fraction cut by arc length later).
Polyline repeatLaps(const Polyline& lap, double laps) {
  Polyline p = lap;
  for (int k = 1; k < static_cast<int>(std::ceil(laps)); ++k) p.insert(p.end(), lap.begin() + 1, lap.end());
  return p;
}

std::vector<double> cumulativeLength(const Polyline& p) {
  std::vector<double> s(p.size(), 0.0);
  for (std::size_t i = 1; i < p.size(); ++i) s[i] = s[i - 1] + (p[i] - p[i - 1]).norm();
  return s;
}

}  // namespace

std::string patternName(MissionPattern p) {
  switch (p) {
    case MissionPattern::kLawnmower:
      return "lawnmower";
    case MissionPattern::kOutAndBack:
      return "out_and_back";
    case MissionPattern::kLoop:
      return "loop";
    case MissionPattern::kFigureEight:
      return "figure_eight";
  }
  return "unknown";
}

bool parsePattern(const std::string& name, MissionPattern* out) {
  for (auto p :
       {MissionPattern::kLawnmower, MissionPattern::kOutAndBack, MissionPattern::kLoop, MissionPattern::kFigureEight}) {
    if (patternName(p) == name) {
      *out = p;
      return true;
    }
  }
  return false;
}

std::string MissionSpec::validate() const {
  std::ostringstream os;
  auto positive = [&](const char* name, double v) {
    if (os.tellp() == 0 && !(std::isfinite(v) && v > 0)) os << name << " = " << v << " must be positive";
  };
  positive("length_m", length_m);
  positive("width_m", width_m);
  positive("leg_spacing_m", leg_spacing_m);
  positive("laps", laps);
  positive("speed_m_s", speed_m_s);
  positive("frame_period_s", frame_period_s);
  positive("altitude_m", altitude_m);
  positive("altitude_period_m", altitude_period_m);
  positive("wobble_period_m", wobble_period_m);
  if (os.tellp() != 0) return os.str();
  if (!start_m.allFinite() || !std::isfinite(heading_rad) || !std::isfinite(camera_yaw_offset_rad) ||
      !std::isfinite(start_time_s) || !std::isfinite(wobble_yaw_rad)) {
    return "start_m, heading_rad, camera_yaw_offset_rad, wobble_yaw_rad and start_time_s must be finite";
  }
  if (!(altitude_amplitude_m >= 0 && altitude_amplitude_m < altitude_m)) {
    os << "altitude_amplitude_m = " << altitude_amplitude_m << " must be in [0, altitude_m)";
  } else if (pattern == MissionPattern::kLawnmower && width_m / leg_spacing_m > 200) {
    os << "lawnmower with more than 200 legs (width_m / leg_spacing_m)";
  } else if (laps > 20) {
    os << "laps = " << laps << " is more than 20";
  }
  return os.str();
}

std::vector<MissionFrame> planMission(const MissionSpec& spec) {
  const std::string bad = spec.validate();
  if (!bad.empty()) throw std::invalid_argument("mission: " + bad);

  Polyline local;
  double keep_fraction = 1.0;  // of the repeated laps
  switch (spec.pattern) {
    case MissionPattern::kLawnmower:
      local = lawnmower(spec);
      break;
    case MissionPattern::kOutAndBack:
      local = outAndBack(spec);
      break;
    case MissionPattern::kLoop:
    case MissionPattern::kFigureEight: {
      const Polyline lap = spec.pattern == MissionPattern::kLoop ? roundedRectangle(spec) : figureEight(spec);
      local = repeatLaps(lap, spec.laps);
      keep_fraction = spec.laps / std::ceil(spec.laps);
      break;
    }
  }
  // Turn the pattern so that its initial direction of travel is heading_rad.
  const Eigen::Vector2d d0 = local[std::min<std::size_t>(5, local.size() - 1)] - local[0];
  const double turn = spec.heading_rad - std::atan2(d0.y(), d0.x());
  const Eigen::Matrix2d rot = Pose2(0, 0, turn).rotation();

  const std::vector<double> s = cumulativeLength(local);
  const double total = s.back() * keep_fraction;
  const double step = spec.speed_m_s * spec.frame_period_s;
  std::vector<MissionFrame> frames;
  std::size_t seg = 0;
  for (int k = 0;; ++k) {
    const double at = k * step;
    if (at > total + 1e-9) break;
    while (seg + 2 < s.size() && s[seg + 1] < at) ++seg;
    const double len = std::max(s[seg + 1] - s[seg], 1e-12);
    const double f = std::clamp((at - s[seg]) / len, 0.0, 1.0);
    const Eigen::Vector2d p = local[seg] + f * (local[seg + 1] - local[seg]);
    // Direction of travel from a chord of about 20 cm, smoother than one dense segment.
    const std::size_t a = seg >= 10 ? seg - 10 : 0, b = std::min(seg + 11, local.size() - 1);
    const Eigen::Vector2d dir = (local[b] - local[a]).normalized();
    const double travel = std::atan2(dir.y(), dir.x()) + turn;
    const double wobble = spec.wobble_yaw_rad * std::sin(2 * M_PI * at / spec.wobble_period_m);
    MissionFrame fr;
    const Eigen::Vector2d world = spec.start_m + rot * p;
    fr.pose = Pose2(world.x(), world.y(), travel + wobble + spec.camera_yaw_offset_rad);
    fr.altitude_m = spec.altitude_m + spec.altitude_amplitude_m * std::sin(2 * M_PI * at / spec.altitude_period_m);
    fr.stamp_s = spec.start_time_s + k * spec.frame_period_s;
    fr.path_m = at;
    fr.velocity_m_s = spec.speed_m_s * Eigen::Vector2d(std::cos(travel), std::sin(travel));
    frames.push_back(fr);
  }
  return frames;
}

}  // namespace core
}  // namespace uw_multislam
