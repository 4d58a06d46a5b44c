#include "uw_multislam/core/frontend/input_pairing.h"

#include <cmath>
#include <sstream>

namespace uw_multislam {
namespace core {

std::string InputPairingOptions::validate() const {
  std::ostringstream os;
  if (!(sync_max_interval_s > 0))
    os << "sync_max_interval_s = " << sync_max_interval_s << ": must be positive";
  else if (!(std::isfinite(altitude_max_age_s) && altitude_max_age_s > 0))
    os << "altitude_max_age_s = " << altitude_max_age_s << ": must be positive";
  else if (!(std::isfinite(reorder_tolerance_s) && reorder_tolerance_s >= 0))
    os << "reorder_tolerance_s = " << reorder_tolerance_s << ": must be >= 0";
  else if (max_waiting < 1)
    os << "max_waiting must be at least 1";
  else if (!altitude_topic && !(std::isfinite(fixed_altitude_m) && fixed_altitude_m > 0))
    os << "fixed_altitude_m = " << fixed_altitude_m << ": must be positive without an altitude topic";
  else if (!(input_timeout_s > 0))
    os << "input_timeout_s = " << input_timeout_s << ": must be positive";
  else if (!(std::isfinite(fallback_altitude_m) && fallback_altitude_m >= 0))
    os << "fallback_altitude_m = " << fallback_altitude_m << ": must be >= 0 (0 = off)";
  return os.str();
}

CameraInfoChoice nearestCameraInfo(const std::deque<double>& stamps, double image_stamp_s, double max_interval_s,
                                   bool final_answer) {
  CameraInfoChoice c;
  double best = std::numeric_limits<double>::infinity();
  bool later = false;  // one at or after the stamp has arrived: later ones cannot be nearer
  for (std::size_t i = 0; i < stamps.size(); ++i) {
    later = later || stamps[i] >= image_stamp_s;
    const double d = std::abs(stamps[i] - image_stamp_s);
    if (d <= max_interval_s && d <= best) best = d, c.index = static_cast<int>(i);  // the latest of equals
  }
  // Without a candidate yet, a later camera_info does not settle it: the image's own may come late.
  c.decided = final_answer || best == 0.0 || (later && c.index >= 0);
  return c;
}

InputSilence inputSilence(const InputPairingCounts& c, const InputPairingOptions& options, double started, double now,
                          bool fallback_camera_in_use) {
  const double timeout = options.input_timeout_s;
  InputSilence s;
  s.camera_info_arrives = c.last_camera_info > 0 && now - c.last_camera_info <= timeout;
  s.altitude_arrives = c.last_altitude > 0 && now - c.last_altitude <= timeout;
  const double image = c.last_image;
  // No image: a wrong topic or transport when none ever came (and start-up is long past), or a
  // dead camera when camera_info or altitude keep coming. A pause of every input (a bag that
  // ended) is not a silent image.
  const bool others = s.camera_info_arrives || s.altitude_arrives;
  if ((image <= 0 && now - started > timeout) || (image > 0 && now - image > timeout && others)) {
    s.kind = InputSilence::Kind::kNoImage;
    s.image_ever = image > 0;
    s.for_s = now - (image > 0 ? image : started);
    return s;
  }
  if (image <= 0 || now - image > timeout) return s;  // no images (a pause of every input): nothing to pair
  if (c.images_since_paired == 0 || now - c.first_image_since_paired <= timeout) return s;  // pairs are coming
  s.for_s = now - c.first_image_since_paired;
  const double info_age = now - (c.last_camera_info > 0 ? c.last_camera_info : started);
  if (info_age > timeout && !fallback_camera_in_use) {
    s.kind = InputSilence::Kind::kNoCameraInfo;
  } else if (options.altitude_topic && c.images_since_altitude > 0 && now - c.first_image_since_altitude > timeout) {
    s.kind = InputSilence::Kind::kNoAltitude;
  } else {
    s.kind = InputSilence::Kind::kStampsApart;
  }
  return s;
}

}  // namespace core
}  // namespace uw_multislam
