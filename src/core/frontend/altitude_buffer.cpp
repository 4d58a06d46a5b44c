#include "uw_multislam/core/frontend/altitude_buffer.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace uw_multislam {
namespace core {

namespace {
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
bool valid(double altitude_m) { return std::isfinite(altitude_m) && altitude_m > 0; }
}  // namespace

std::string AltitudeBufferOptions::validate() const {
  std::ostringstream os;
  if (!(std::isfinite(max_age_s) && max_age_s > 0)) {
    os << "max_age_s = " << max_age_s << ": must be positive";
  } else if (!(std::isfinite(reorder_tolerance_s) && reorder_tolerance_s >= 0)) {
    os << "reorder_tolerance_s = " << reorder_tolerance_s << ": must be >= 0";
  } else if (capacity < 2) {
    os << "capacity = " << capacity << ": must be at least 2 (interpolation needs two readings)";
  }
  return os.str();
}

std::string altitudeStatusName(AltitudeStatus s) {
  switch (s) {
    case AltitudeStatus::kExact:
      return "exact";
    case AltitudeStatus::kInterpolated:
      return "interpolated";
    case AltitudeStatus::kNearest:
      return "nearest";
    case AltitudeStatus::kInvalid:
      return "invalid";
    case AltitudeStatus::kStale:
      return "stale";
    case AltitudeStatus::kPending:
      return "pending";
  }
  return "?";
}

AltitudeBuffer::AltitudeBuffer(const AltitudeBufferOptions& options) : options_(options) {
  const std::string bad = options_.validate();
  if (!bad.empty()) throw std::invalid_argument("altitude buffer: " + bad);
}

AltitudeBuffer::AddResult AltitudeBuffer::add(double stamp_s, double altitude_m) {
  if (!std::isfinite(stamp_s)) return AddResult::kRefused;
  const Reading r{stamp_s, valid(altitude_m) ? altitude_m : kNaN};
  AddResult result = AddResult::kAdded;
  if (!readings_.empty() && stamp_s < newest() - options_.reorder_tolerance_s) {
    readings_.clear();  // a bag that loops, a clock reset: the old readings belong to another time
    result = AddResult::kCleared;
  }
  auto it = std::lower_bound(readings_.begin(), readings_.end(), stamp_s,
                             [](const Reading& a, double t) { return a.stamp_s < t; });
  if (it != readings_.end() && it->stamp_s == stamp_s) {
    *it = r;
    return AddResult::kReplaced;
  }
  readings_.insert(it, r);
  while (readings_.size() > options_.capacity) readings_.pop_front();
  return result;
}

AltitudeAt AltitudeBuffer::use(const Reading& r, double stamp_s, AltitudeStatus status) const {
  AltitudeAt out;
  out.age_s = std::abs(stamp_s - r.stamp_s);
  if (out.age_s > options_.max_age_s) {
    out.status = AltitudeStatus::kStale;
    out.altitude_m = kNaN;
  } else if (!valid(r.altitude_m)) {
    out.status = AltitudeStatus::kInvalid;
    out.altitude_m = kNaN;
  } else {
    out.status = status;
    out.altitude_m = r.altitude_m;
  }
  return out;
}

AltitudeAt AltitudeBuffer::at(double stamp_s, bool final_answer) const {
  AltitudeAt out;
  out.altitude_m = kNaN;
  if (!std::isfinite(stamp_s)) {
    out.status = AltitudeStatus::kStale;
    return out;
  }
  if (readings_.empty()) {
    out.status = final_answer ? AltitudeStatus::kStale : AltitudeStatus::kPending;
    return out;
  }
  if (!final_answer && (stamp_s > newest() || stamp_s < newest() - options_.reorder_tolerance_s)) {
    out.status = AltitudeStatus::kPending;  // a later reading may come, or a loop may clear the buffer
    return out;
  }
  // b: the first reading at or after the stamp; a: the one before it.
  auto b = std::lower_bound(readings_.begin(), readings_.end(), stamp_s,
                            [](const Reading& r, double t) { return r.stamp_s < t; });
  if (b != readings_.end() && b->stamp_s == stamp_s) return use(*b, stamp_s, AltitudeStatus::kExact);
  if (b == readings_.end()) return use(readings_.back(), stamp_s, AltitudeStatus::kNearest);
  if (b == readings_.begin()) return use(*b, stamp_s, AltitudeStatus::kNearest);
  const Reading& ra = *std::prev(b);
  const Reading& rb = *b;
  const double gap = rb.stamp_s - ra.stamp_s;
  if (gap > options_.max_age_s) {
    const Reading& nearest = stamp_s - ra.stamp_s <= rb.stamp_s - stamp_s ? ra : rb;
    return use(nearest, stamp_s, AltitudeStatus::kNearest);
  }
  out.age_s = std::min(stamp_s - ra.stamp_s, rb.stamp_s - stamp_s);
  if (!valid(ra.altitude_m) || !valid(rb.altitude_m)) {
    out.status = AltitudeStatus::kInvalid;
    return out;
  }
  const double w = (stamp_s - ra.stamp_s) / gap;
  out.status = AltitudeStatus::kInterpolated;
  out.altitude_m = ra.altitude_m + w * (rb.altitude_m - ra.altitude_m);
  return out;
}

}  // namespace core
}  // namespace uw_multislam
