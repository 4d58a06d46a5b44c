// The altitude at an image's stamp from the recent altimeter readings: the altimeter is usually slower than the camera
// (2 Hz against 10 Hz), so pairing each image with one reading would drop most images. The buffer keeps the last
// readings (sorted by stamp, at most `capacity`) and answers, for an image stamp t:
//
//   a reading stamped exactly t                          that reading            kExact
//   readings a < t < b with b - a <= max_age_s           linear between a and b  kInterpolated
//   else the nearest reading within max_age_s of t       that reading            kNearest
//   else                                                 nothing                 kStale
//
// Live, the reading after t may not have arrived yet: at() then answers kPending (t after the
// newest reading, or no reading yet) and the caller waits a little; once it stops waiting,
// at(t, /*final_answer=*/true) decides with what is there (the last reading if it is within
// max_age_s, else kStale). An image stamp more than reorder_tolerance_s before the newest
// reading is also kPending: the altimeter is ahead of the camera, e.g. a looping bag whose
// first altitude has not come round yet (it will clear the buffer).
//
// Readings: a non-finite or non-positive altitude is kept as an invalid reading (the caller
// turns out-of-range values into NaN): an answer that uses one is kInvalid (the odometry then
// reuses its last valid altitude, as for a bad reading paired directly). A reading at the stamp
// of one already there replaces it. A reading up to reorder_tolerance_s before the newest is
// inserted in order; further back (a bag that loops, a clock reset) clears the buffer first.
// A non-finite stamp is refused. When full, the oldest reading is dropped.
//
// ROS-free; the odometry nodelet feeds it sensor_msgs/Range readings. Tested in
// test/core/test_altitude_buffer.cpp.
#pragma once

#include <cstddef>
#include <deque>
#include <string>

namespace uw_multislam {
namespace core {

struct AltitudeBufferOptions {
  double max_age_s = 1.0;            // largest gap interpolated over, and largest age of a reading used alone
  double reorder_tolerance_s = 1.0;  // readings at most this far back are inserted; further back clear the buffer
  std::size_t capacity = 1000;       // readings kept (the oldest dropped)
  /// Empty when valid, else a sentence naming the bad value.
  std::string validate() const;
};

enum class AltitudeStatus { kExact, kInterpolated, kNearest, kInvalid, kStale, kPending };
std::string altitudeStatusName(AltitudeStatus s);

struct AltitudeAt {
  AltitudeStatus status = AltitudeStatus::kPending;
  double altitude_m = 0.0;  // valid for kExact, kInterpolated, kNearest; NaN otherwise
  double age_s = 0.0;       // distance from the stamp to the nearest reading used (0 when exact)
  /// True when the answer carries a valid altitude.
  bool ok() const {
    return status == AltitudeStatus::kExact || status == AltitudeStatus::kInterpolated ||
           status == AltitudeStatus::kNearest;
  }
};

class AltitudeBuffer {
 public:
  enum class AddResult { kAdded, kReplaced, kCleared, kRefused };

  explicit AltitudeBuffer(const AltitudeBufferOptions& options = AltitudeBufferOptions());
  /// Adds a reading (altitude NaN or <= 0: an invalid reading); kCleared when its stamp jumped
  /// back by more than reorder_tolerance_s and the older readings were dropped.
  AddResult add(double stamp_s, double altitude_m);
  /// The altitude at `stamp_s` (see the table above). Without final_answer, kPending while a
  /// later reading may still change the answer.
  AltitudeAt at(double stamp_s, bool final_answer = false) const;
  void clear() { readings_.clear(); }
  std::size_t size() const { return readings_.size(); }
  bool empty() const { return readings_.empty(); }
  /// Stamp of the newest reading; meaningless when empty.
  double newest() const { return readings_.back().stamp_s; }
  const AltitudeBufferOptions& options() const { return options_; }

 private:
  struct Reading {
    double stamp_s;
    double altitude_m;  // NaN when invalid
  };
  AltitudeAt use(const Reading& r, double stamp_s, AltitudeStatus status) const;

  AltitudeBufferOptions options_;
  std::deque<Reading> readings_;  // ascending stamps, no two equal
};

}  // namespace core
}  // namespace uw_multislam
