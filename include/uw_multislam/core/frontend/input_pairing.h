// Pairs each image with its camera calibration and its altitude by stamp, for a live stream where
// the three travel on separate connections and arrive in any order (the camera driver, its
// camera_info and a slower altimeter). ROS-free: the odometry nodelet converts its messages and
// feeds them in; time ("now", wall seconds) is an argument of every call, so tests need no clock.
//
// Each image waits, in arrival order, in a short list of pending images, for
//   - its camera_info: the one with the nearest stamp within sync_max_interval_s, reused by as
//     many images as need it. Decided as soon as one with the image's own stamp has arrived, or a
//     later one while one within the bound is there (later ones cannot be nearer). One per image,
//     not just the latest, so a change of intrinsics takes effect at its own image; nearest, not
//     exact, so a driver that stamps camera_info a little apart still pairs.
//   - its altitude (altitude_topic): core::AltitudeBuffer over the recent readings, linear between
//     the two around the image stamp (at most altitude_max_age_s apart), else the nearest within
//     altitude_max_age_s. Decided as soon as a reading at or after the image stamp has arrived, so
//     every image of a 10 Hz camera is used with a 2 Hz altimeter (an image waits ~0.5 s then).
// An image waits at most altitude_max_age_s (wall time) from its arrival; it is then decided with
// what has arrived. At most max_waiting images wait; beyond that the oldest is decided at once.
// Images without a camera_info or an altitude by then are skipped and counted; their stamps travel
// on with the next image paired (Paired::passed_over: seen, so our own skips are no time gap).
//
// Without any camera_info ever, the fallback calibration (given at construction: the nodelet's
// ~camera_info_url) is used by images that waited their longest, and from then on by every image,
// until a camera_info arrives. Without an altitude topic every image takes the fixed altitude. An
// image whose altitude is stale while the altitude input is silent (images have come without any
// reading for input_timeout_s) takes fallback_altitude_m when it is > 0, and is skipped otherwise.
//
// Not thread-safe: the caller serialises the calls (the nodelet's pairing mutex). Tested in
// test/core/test_input_pairing.cpp.
#pragma once

#include <cstddef>
#include <deque>
#include <limits>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "uw_multislam/core/frontend/altitude_buffer.h"

namespace uw_multislam {
namespace core {

struct InputPairingOptions {
  double sync_max_interval_s = 0.1;  // largest image - camera_info stamp difference
  double altitude_max_age_s = 1.0;   // largest altitude gap interpolated / age used alone; longest wait
  double reorder_tolerance_s = 1.0;  // camera_info / altitude stamps further back: a new clock
  std::size_t max_waiting = 20;      // images waiting beyond this: the oldest decided at once
  bool altitude_topic = true;        // false: every image takes fixed_altitude_m
  double fixed_altitude_m = 0.0;
  double input_timeout_s = 5.0;      // images without any altitude reading this long: the input is silent
  double fallback_altitude_m = 0.0;  // > 0: taken by images without altitude while the input is silent
  /// Empty when valid, else a sentence naming the bad value.
  std::string validate() const;
};

/// Where a paired image's altitude comes from.
enum class PairedAltitude {
  kReading,         // the altimeter at the image stamp (AltitudeBuffer)
  kInvalidReading,  // it would use an invalid reading: NaN, the odometry reuses the last valid one
  kFallback,        // the altitude input is silent: fallback_altitude_m
  kFixed,           // no altitude topic: fixed_altitude_m
};

/// What decided the images (the nodelet's diagnostics; arrivals for silentInput).
struct InputPairingCounts {
  long images = 0, camera_infos = 0, altitudes = 0;  // arrivals
  long paired = 0, skipped_no_camera_info = 0, skipped_no_altitude = 0;
  long altitude_clears = 0;     // altitude stamps jumped back: the earlier readings were dropped
  long camera_info_clears = 0;  // camera_info stamps jumped back
  double last_image = 0.0, last_camera_info = 0.0, last_altitude = 0.0;  // wall seconds of the last (0: none)
  long images_since_altitude = 0, images_since_paired = 0;               // images since the last reading / pairing
  double first_image_since_altitude = 0.0, first_image_since_paired = 0.0;
};

/// Why images are not paired although they arrive (InputPairing::silence).
struct InputSilence {
  enum class Kind { kNone, kNoImage, kNoCameraInfo, kNoAltitude, kStampsApart };
  Kind kind = Kind::kNone;
  double for_s = 0.0;      // how long (kNoImage: since start when no image ever came)
  bool image_ever = true;  // kNoImage: whether any image came at all
  bool camera_info_arrives = false, altitude_arrives = false;  // within input_timeout_s
};

/// An image decided: paired, or skipped for want of a camera_info or an altitude.
template <class Image, class Info>
struct PairingDecision {
  enum class Kind { kPaired, kNoCameraInfo, kNoAltitude };
  Kind kind = Kind::kPaired;
  Image image;
  double stamp_s = 0.0;
  Info info{};                   // kPaired
  bool fallback_camera = false;  // kPaired: the fallback calibration
  bool first_fallback = false;   // kPaired: the first image to use it (the nodelet warns once)
  double altitude_m = std::numeric_limits<double>::quiet_NaN();  // kPaired; NaN for kInvalidReading
  PairedAltitude altitude = PairedAltitude::kFixed;
  std::vector<double> passed_over;  // kPaired: stamps of the images skipped since the last paired one
};

/// The camera_info rule on stamps alone (see the file comment): the index in `stamps` of the one
/// to use (-1: none within the bound), and whether that is decided (a nearer one cannot come any
/// more, or final_answer).
struct CameraInfoChoice {
  bool decided = false;
  int index = -1;
};
CameraInfoChoice nearestCameraInfo(const std::deque<double>& stamps, double image_stamp_s, double max_interval_s,
                                   bool final_answer);

template <class Image, class Info>
class InputPairing {
 public:
  using Decision = PairingDecision<Image, Info>;
  using Decisions = std::vector<Decision>;
  /// The camera_infos kept for the search (the latest).
  static constexpr std::size_t kCameraInfosKept = 100;
  /// Stamps of consecutive skipped images kept for the next paired one; beyond, the oldest are
  /// forgotten, and the gap they leave may start a session, as a long outage should.
  static constexpr std::size_t kMaxSkippedStamps = 4096;

  /// `fallback`: the calibration for images when no camera_info ever arrives (none: they are skipped).
  InputPairing(const InputPairingOptions& options, double now, std::optional<Info> fallback = std::nullopt)
      : options_(options), started_(now), fallback_(std::move(fallback)) {
    AltitudeBufferOptions a;
    a.max_age_s = options.altitude_max_age_s;
    a.reorder_tolerance_s = options.reorder_tolerance_s;
    altitudes_ = AltitudeBuffer(a);
  }

  Decisions addImage(Image image, double stamp_s, double now) {
    ++counts_.images, counts_.last_image = now;
    if (counts_.images_since_altitude++ == 0) counts_.first_image_since_altitude = now;
    if (counts_.images_since_paired++ == 0) counts_.first_image_since_paired = now;
    pending_.push_back({std::move(image), stamp_s, now});
    return decide(now);
  }

  Decisions addCameraInfo(Info info, double stamp_s, double now) {
    ++counts_.camera_infos, counts_.last_camera_info = now;
    // A stamp far back (a bag that loops): the older ones belong to another time.
    if (!info_stamps_.empty() && stamp_s < info_stamps_.back() - options_.reorder_tolerance_s) {
      infos_.clear(), info_stamps_.clear();
      ++counts_.camera_info_clears;
    }
    infos_.push_back(std::move(info)), info_stamps_.push_back(stamp_s);
    while (infos_.size() > kCameraInfosKept) infos_.pop_front(), info_stamps_.pop_front();
    return decide(now);
  }

  /// An altitude reading (NaN: an invalid one, kept as such). `cleared` (may be null): set when its
  /// stamp jumped back and the earlier readings were dropped.
  Decisions addAltitude(double stamp_s, double altitude_m, double now, bool* cleared = nullptr) {
    ++counts_.altitudes, counts_.last_altitude = now, counts_.images_since_altitude = 0;
    const bool clears = altitudes_.add(stamp_s, altitude_m) == AltitudeBuffer::AddResult::kCleared;
    counts_.altitude_clears += clears;
    if (cleared) *cleared = clears;
    return decide(now);
  }

  /// Decides the images that waited their longest (the nodelet's timer, when no message comes).
  Decisions update(double now) { return decide(now); }

  const InputPairingCounts& counts() const { return counts_; }
  std::size_t waiting() const { return pending_.size(); }
  bool fallbackCameraInUse() const { return fallback_in_use_; }
  /// Stamp of the newest altitude reading (NaN: none).
  double newestAltitude() const {
    return altitudes_.empty() ? std::numeric_limits<double>::quiet_NaN() : altitudes_.newest();
  }
  /// Why images are not paired although they arrive, at `now` (kind kNone: they are, or no image
  /// comes while every input pauses: a bag that ended).
  InputSilence silence(double now) const;

 private:
  struct Pending {
    Image image;
    double stamp_s;
    double arrived;  // wall seconds
  };

  Decisions decide(double now) {
    Decisions out;
    while (!pending_.empty()) {
      const double stamp = pending_.front().stamp_s;
      // Waited long enough, or too many waiting: decide with what has arrived.
      const bool final_answer =
          now - pending_.front().arrived >= options_.altitude_max_age_s || pending_.size() > options_.max_waiting;
      const CameraInfoChoice info = nearestCameraInfo(info_stamps_, stamp, options_.sync_max_interval_s, final_answer);
      // No camera_info ever: the fallback calibration, once an image has waited its longest.
      const bool fallback =
          info.index < 0 && fallback_ && counts_.camera_infos == 0 && (final_answer || fallback_in_use_);
      if (!info.decided && !fallback) return out;
      AltitudeAt altitude;
      if (options_.altitude_topic) {
        altitude = altitudes_.at(stamp, final_answer);
        if (altitude.status == AltitudeStatus::kPending) return out;
      }
      Decision d;
      d.image = std::move(pending_.front().image);
      d.stamp_s = stamp;
      pending_.pop_front();
      if (info.index < 0 && !fallback) {
        out.push_back(skip(std::move(d), Decision::Kind::kNoCameraInfo));
        continue;
      }
      d.info = fallback ? *fallback_ : infos_[static_cast<std::size_t>(info.index)];
      d.fallback_camera = fallback;
      d.first_fallback = fallback && !fallback_in_use_;
      fallback_in_use_ = fallback_in_use_ || fallback;
      if (!options_.altitude_topic) {
        d.altitude = PairedAltitude::kFixed, d.altitude_m = options_.fixed_altitude_m;
      } else if (altitude.status == AltitudeStatus::kStale) {
        // The fallback altitude only while the input is silent (images without a reading for input_timeout_s).
        const bool silent =
            counts_.images_since_altitude > 0 && now - counts_.first_image_since_altitude >= options_.input_timeout_s;
        if (!(options_.fallback_altitude_m > 0 && silent)) {
          out.push_back(skip(std::move(d), Decision::Kind::kNoAltitude));
          continue;
        }
        d.altitude = PairedAltitude::kFallback, d.altitude_m = options_.fallback_altitude_m;
      } else if (altitude.status == AltitudeStatus::kInvalid) {
        d.altitude = PairedAltitude::kInvalidReading;
      } else {
        d.altitude = PairedAltitude::kReading, d.altitude_m = altitude.altitude_m;
      }
      d.passed_over = std::move(skipped_stamps_);
      skipped_stamps_.clear();
      ++counts_.paired;
      counts_.images_since_paired = 0;
      out.push_back(std::move(d));
    }
    return out;
  }

  Decision skip(Decision d, typename Decision::Kind kind) {
    d.kind = kind;
    ++(kind == Decision::Kind::kNoCameraInfo ? counts_.skipped_no_camera_info : counts_.skipped_no_altitude);
    if (skipped_stamps_.size() >= kMaxSkippedStamps) skipped_stamps_.erase(skipped_stamps_.begin());
    skipped_stamps_.push_back(d.stamp_s);
    return d;
  }

  InputPairingOptions options_;
  double started_;
  std::optional<Info> fallback_;
  bool fallback_in_use_ = false;
  std::deque<Pending> pending_;
  std::deque<Info> infos_;          // the recent camera_infos, in arrival order
  std::deque<double> info_stamps_;  // their stamps
  AltitudeBuffer altitudes_;
  std::vector<double> skipped_stamps_;
  InputPairingCounts counts_;
};

/// The silence rule on the counts alone (InputPairing::silence uses it).
InputSilence inputSilence(const InputPairingCounts& counts, const InputPairingOptions& options, double started,
                          double now, bool fallback_camera_in_use);

template <class Image, class Info>
InputSilence InputPairing<Image, Info>::silence(double now) const {
  return inputSilence(counts_, options_, started_, now, fallback_in_use_);
}

}  // namespace core
}  // namespace uw_multislam
