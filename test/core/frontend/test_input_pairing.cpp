// InputPairing: each image paired with its camera_info and altitude by stamp, with the waiting
// rules of the odometry nodelet; time is given to every call (no clock, no sleep).
#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

#include "uw_multislam/core/frontend/input_pairing.h"

namespace uw_multislam {
namespace core {
namespace {

using Pairing = InputPairing<int, std::string>;  // images by number, camera_infos by name
using Kind = Pairing::Decision::Kind;

InputPairingOptions options() {
  InputPairingOptions o;
  o.sync_max_interval_s = 0.1;
  o.altitude_max_age_s = 1.0;
  o.reorder_tolerance_s = 1.0;
  o.max_waiting = 20;
  o.input_timeout_s = 5.0;
  return o;
}

InputPairingOptions withoutAltitude() {
  InputPairingOptions o = options();
  o.altitude_topic = false;
  o.fixed_altitude_m = 2.5;
  return o;
}

// The decisions made so far, in order.
struct Log {
  std::vector<Pairing::Decision> all;
  void add(Pairing::Decisions d) {
    for (auto& x : d) all.push_back(std::move(x));
  }
};

TEST(InputPairing, TakesTheNearestCameraInfoWithinTheBoundAndDecidesWhenNoNearerOneCanCome) {
  InputPairingOptions o = withoutAltitude();
  o.sync_max_interval_s = 0.25;
  Pairing p(o, 0.0);
  Log log;
  log.add(p.addCameraInfo("a", 9.875, 0.0));
  // Image at 10.0: "a" is 0.125 away, but one stamped nearer may still come.
  log.add(p.addImage(1, 10.0, 0.0));
  EXPECT_TRUE(log.all.empty());
  EXPECT_EQ(p.waiting(), 1u);
  // A later one while one within the bound is there decides it: the nearer of the two.
  log.add(p.addCameraInfo("b", 10.0625, 0.01));
  ASSERT_EQ(log.all.size(), 1u);
  EXPECT_EQ(log.all[0].kind, Kind::kPaired);
  EXPECT_EQ(log.all[0].image, 1);
  EXPECT_EQ(log.all[0].info, "b");
  EXPECT_EQ(log.all[0].altitude, PairedAltitude::kFixed);
  EXPECT_EQ(log.all[0].altitude_m, 2.5);
  // One with the image's own stamp decides at once, and is reused by later images.
  log.add(p.addCameraInfo("c", 11.0, 0.02));
  log.add(p.addImage(2, 11.0, 0.03));
  ASSERT_EQ(log.all.size(), 2u);
  EXPECT_EQ(log.all[1].info, "c");
  // Of two at the same distance, the latest.
  log.add(p.addCameraInfo("d", 11.25, 0.04));
  log.add(p.addCameraInfo("e", 11.75, 0.05));
  log.add(p.addImage(3, 11.5, 0.06));
  ASSERT_EQ(log.all.size(), 3u);
  EXPECT_EQ(log.all[2].info, "e");
  EXPECT_EQ(p.counts().paired, 3);
}

TEST(InputPairing, ALaterCameraInfoOutsideTheBoundDoesNotDecideAnImageWithoutACandidate) {
  Pairing p(withoutAltitude(), 0.0);
  Log log;
  log.add(p.addImage(1, 10.0, 0.0));
  log.add(p.addCameraInfo("far", 10.5, 0.1));  // later, but 0.5 s away: the image's own may still come
  EXPECT_TRUE(log.all.empty());
  log.add(p.addCameraInfo("own", 10.0, 0.2));  // late, on its own connection
  ASSERT_EQ(log.all.size(), 1u);
  EXPECT_EQ(log.all[0].info, "own");
}

TEST(InputPairing, AChangeOfCameraTakesEffectAtItsOwnImage) {
  Pairing p(withoutAltitude(), 0.0);
  Log log;
  // The camera_infos come first, the images later (a slower connection): each image its own.
  log.add(p.addCameraInfo("old", 1.0, 0.0));
  log.add(p.addCameraInfo("old", 1.125, 0.0));
  log.add(p.addCameraInfo("new", 1.25, 0.0));
  for (int k = 0; k < 3; ++k) log.add(p.addImage(k, 1.0 + 0.125 * k, 0.1));
  ASSERT_EQ(log.all.size(), 3u);
  EXPECT_EQ(log.all[0].info, "old");
  EXPECT_EQ(log.all[1].info, "old");
  EXPECT_EQ(log.all[2].info, "new");
}

TEST(InputPairing, AnImageWithoutACameraInfoWithinTheBoundIsSkippedAfterItsLongestWait) {
  Pairing p(withoutAltitude(), 0.0);
  Log log;
  log.add(p.addCameraInfo("a", 10.0, 0.0));
  log.add(p.addImage(1, 10.5, 0.0));  // 0.5 s from the only camera_info: none within 0.1 s
  log.add(p.update(0.99));
  EXPECT_TRUE(log.all.empty()) << "decided before the wall-time limit";
  log.add(p.update(1.0));  // waited altitude_max_age_s
  ASSERT_EQ(log.all.size(), 1u);
  EXPECT_EQ(log.all[0].kind, Kind::kNoCameraInfo);
  EXPECT_EQ(log.all[0].stamp_s, 10.5);
  EXPECT_EQ(p.counts().skipped_no_camera_info, 1);
  // Its stamp travels on with the next image paired (seen: no time gap).
  log.add(p.addCameraInfo("b", 10.6, 1.1));
  log.add(p.addImage(2, 10.6, 1.1));
  ASSERT_EQ(log.all.size(), 2u);
  EXPECT_EQ(log.all[1].kind, Kind::kPaired);
  EXPECT_EQ(log.all[1].passed_over, std::vector<double>({10.5}));
  log.add(p.addImage(3, 10.6, 1.2));
  EXPECT_TRUE(log.all[2].passed_over.empty()) << "handed on once";
}

TEST(InputPairing, PairsTheAltitudeByStampAndWaitsForTheReadingAfterTheImage) {
  Pairing p(options(), 0.0);
  Log log;
  for (int k = 0; k <= 4; ++k) log.add(p.addCameraInfo("cam", 100.0 + 0.125 * k, 0.0));
  log.add(p.addAltitude(100.0, 2.0, 0.0));
  // An 8 Hz camera and a 2 Hz altimeter: images after the newest reading wait for the next one.
  for (int k = 0; k <= 3; ++k) log.add(p.addImage(k, 100.0 + 0.125 * k, 0.01 * k));
  ASSERT_EQ(log.all.size(), 1u) << "only the image at the reading's stamp is decided";
  EXPECT_EQ(log.all[0].altitude, PairedAltitude::kReading);
  EXPECT_DOUBLE_EQ(log.all[0].altitude_m, 2.0);
  log.add(p.addAltitude(100.5, 1.5, 0.1));
  ASSERT_EQ(log.all.size(), 4u);
  for (int k = 1; k <= 3; ++k) {
    EXPECT_EQ(log.all[k].image, k);
    EXPECT_EQ(log.all[k].altitude, PairedAltitude::kReading);
    EXPECT_NEAR(log.all[k].altitude_m, 2.0 - 0.125 * k, 1e-12) << "linear between the readings";
  }
}

TEST(InputPairing, AfterItsLongestWaitAnImageTakesTheLastReadingWithinTheAgeOrIsSkipped) {
  Pairing p(options(), 0.0);
  Log log;
  log.add(p.addCameraInfo("cam", 50.125, 0.0));
  log.add(p.addCameraInfo("cam", 51.5, 0.0));
  log.add(p.addAltitude(50.0, 3.0, 0.0));
  log.add(p.addImage(1, 50.125, 0.0));  // 0.125 s after the reading: kept waiting for the next
  log.add(p.update(0.5));
  EXPECT_TRUE(log.all.empty());
  log.add(p.update(1.0));
  ASSERT_EQ(log.all.size(), 1u);
  EXPECT_EQ(log.all[0].altitude, PairedAltitude::kReading);
  EXPECT_DOUBLE_EQ(log.all[0].altitude_m, 3.0);
  // 1.5 s after the reading: beyond altitude_max_age_s, skipped and counted.
  log.add(p.addImage(2, 51.5, 2.0));
  log.add(p.update(3.0));
  ASSERT_EQ(log.all.size(), 2u);
  EXPECT_EQ(log.all[1].kind, Kind::kNoAltitude);
  EXPECT_EQ(p.counts().skipped_no_altitude, 1);
}

TEST(InputPairing, AnImageThatWouldUseAnInvalidReadingIsPairedWithoutAltitude) {
  Pairing p(options(), 0.0);
  Log log;
  log.add(p.addCameraInfo("cam", 1.0, 0.0));
  log.add(p.addAltitude(1.0, std::nan(""), 0.0));
  log.add(p.addImage(1, 1.0, 0.0));
  ASSERT_EQ(log.all.size(), 1u);
  EXPECT_EQ(log.all[0].kind, Kind::kPaired);
  EXPECT_EQ(log.all[0].altitude, PairedAltitude::kInvalidReading);
  EXPECT_TRUE(std::isnan(log.all[0].altitude_m));
}

TEST(InputPairing, AltitudeStampsJumpingBackClearTheReadings) {
  Pairing p(options(), 0.0);
  bool cleared = true;
  p.addAltitude(100.0, 2.0, 0.0, &cleared);
  EXPECT_FALSE(cleared);
  p.addAltitude(10.0, 2.0, 0.1, &cleared);  // a bag that loops
  EXPECT_TRUE(cleared);
  EXPECT_EQ(p.counts().altitude_clears, 1);
  EXPECT_EQ(p.newestAltitude(), 10.0);
}

TEST(InputPairing, BeyondTheWaitingBoundTheOldestImageIsDecidedAtOnce) {
  InputPairingOptions o = withoutAltitude();
  o.max_waiting = 3;
  Pairing p(o, 0.0);
  Log log;
  for (int k = 0; k < 3; ++k) log.add(p.addImage(k, 10.0 + k, 0.0));  // no camera_info yet
  EXPECT_TRUE(log.all.empty());
  log.add(p.addImage(3, 13.0, 0.0));  // a fourth: the oldest is decided with what is there
  ASSERT_EQ(log.all.size(), 1u);
  EXPECT_EQ(log.all[0].image, 0);
  EXPECT_EQ(log.all[0].kind, Kind::kNoCameraInfo);
  EXPECT_EQ(p.waiting(), 3u);
}

TEST(InputPairing, TheFallbackCalibrationIsUsedOnlyWhileNoCameraInfoEverCame) {
  Pairing p(withoutAltitude(), 0.0, std::string("file"));
  Log log;
  log.add(p.addImage(1, 10.0, 0.0));
  log.add(p.update(0.5));
  EXPECT_TRUE(log.all.empty()) << "the image's own camera_info may still come";
  log.add(p.update(1.0));
  ASSERT_EQ(log.all.size(), 1u);
  EXPECT_EQ(log.all[0].info, "file");
  EXPECT_TRUE(log.all[0].fallback_camera);
  EXPECT_TRUE(log.all[0].first_fallback);
  EXPECT_TRUE(p.fallbackCameraInUse());
  // From then on without waiting.
  log.add(p.addImage(2, 10.1, 1.1));
  ASSERT_EQ(log.all.size(), 2u);
  EXPECT_EQ(log.all[1].info, "file");
  EXPECT_FALSE(log.all[1].first_fallback);
  // Once a camera_info arrives, only camera_infos.
  log.add(p.addCameraInfo("topic", 10.2, 1.2));
  log.add(p.addImage(3, 10.2, 1.2));
  log.add(p.addImage(4, 20.0, 1.2));
  log.add(p.update(2.2));
  ASSERT_EQ(log.all.size(), 4u);
  EXPECT_EQ(log.all[2].info, "topic");
  EXPECT_EQ(log.all[3].kind, Kind::kNoCameraInfo);
}

TEST(InputPairing, TheFallbackAltitudeOnlyWhileTheAltitudeInputIsSilent) {
  InputPairingOptions o = options();
  o.fallback_altitude_m = 1.6;
  o.input_timeout_s = 5.0;
  Pairing p(o, 0.0);
  Log log;
  // 4 Hz images without any altitude reading: skipped until they have come for input_timeout_s.
  for (int k = 0; k < 40; ++k) {
    log.add(p.addCameraInfo("cam", 0.25 * k, 0.25 * k));
    log.add(p.addImage(k, 0.25 * k, 0.25 * k));
  }
  log.add(p.update(11.0));
  ASSERT_EQ(log.all.size(), 40u);
  int skipped = 0, fallback = 0;
  for (const auto& d : log.all) {
    if (d.kind == Kind::kNoAltitude) {
      ++skipped;
      EXPECT_LT(d.stamp_s, 4.0);  // decided at wall time stamp + 1 s, before the input was silent for 5 s
    } else {
      ++fallback;
      EXPECT_EQ(d.altitude, PairedAltitude::kFallback);
      EXPECT_EQ(d.altitude_m, 1.6);
    }
  }
  EXPECT_EQ(skipped, 16);
  EXPECT_EQ(fallback, 24);
  // A reading ends the silence: the next image without one within the age is skipped again.
  log.add(p.addAltitude(0.0, 2.0, 11.0));
  log.add(p.addCameraInfo("cam", 20.0, 11.25));
  log.add(p.addImage(100, 20.0, 11.25));
  log.add(p.update(12.25));
  EXPECT_EQ(log.all.back().kind, Kind::kNoAltitude);
}

TEST(InputPairing, SaysWhichInputIsSilent) {
  InputPairingOptions o = options();
  o.input_timeout_s = 5.0;
  Pairing p(o, 0.0);
  EXPECT_EQ(p.silence(4.0).kind, InputSilence::Kind::kNone) << "start-up";
  const InputSilence none = p.silence(6.0);
  EXPECT_EQ(none.kind, InputSilence::Kind::kNoImage);
  EXPECT_FALSE(none.image_ever);
  EXPECT_EQ(none.for_s, 6.0);
  // Images, camera_infos, no altitude.
  for (int k = 0; k <= 70; ++k) {
    p.addCameraInfo("cam", 0.1 * k, 0.1 * k);
    p.addImage(k, 0.1 * k, 0.1 * k);
  }
  const InputSilence no_altitude = p.silence(7.0);
  EXPECT_EQ(no_altitude.kind, InputSilence::Kind::kNoAltitude);
  EXPECT_NEAR(no_altitude.for_s, 7.0, 1e-9);
  EXPECT_TRUE(no_altitude.camera_info_arrives);
  EXPECT_FALSE(no_altitude.altitude_arrives);
  // The images stop while camera_infos keep coming: a dead camera.
  p.addCameraInfo("cam", 13.0, 13.0);
  const InputSilence dead = p.silence(13.0);
  EXPECT_EQ(dead.kind, InputSilence::Kind::kNoImage);
  EXPECT_TRUE(dead.image_ever);
  EXPECT_NEAR(dead.for_s, 6.0, 1e-9);
  // Every input pauses (a bag that ended): nothing to say.
  EXPECT_EQ(p.silence(30.0).kind, InputSilence::Kind::kNone);
}

TEST(InputPairing, SaysWhenTheCameraInfoIsMissing) {
  Pairing p(options(), 0.0);
  for (int k = 0; k <= 70; ++k) {
    p.addAltitude(0.1 * k, 2.0, 0.1 * k);
    p.addImage(k, 0.1 * k, 0.1 * k);
  }
  EXPECT_EQ(p.silence(7.0).kind, InputSilence::Kind::kNoCameraInfo);
  // With the fallback calibration in use, a missing camera_info is no silence.
  Pairing f(options(), 0.0, std::string("file"));
  for (int k = 0; k <= 70; ++k) {
    f.addAltitude(0.1 * k, 2.0, 0.1 * k);
    f.addImage(k, 0.1 * k, 0.1 * k);
  }
  EXPECT_TRUE(f.fallbackCameraInUse());
  EXPECT_EQ(f.silence(7.0).kind, InputSilence::Kind::kNone);
}

TEST(InputPairing, SaysWhenTheStampsAreTooFarApart) {
  Pairing p(options(), 0.0);
  for (int k = 0; k <= 70; ++k) {
    p.addAltitude(0.1 * k, 2.0, 0.1 * k);
    p.addCameraInfo("cam", 0.1 * k + 100.0, 0.1 * k);  // 100 s from every image
    p.addImage(k, 0.1 * k, 0.1 * k);
  }
  EXPECT_EQ(p.counts().paired, 0);
  EXPECT_EQ(p.silence(7.0).kind, InputSilence::Kind::kStampsApart);
}

TEST(InputPairing, OptionsAreValidated) {
  EXPECT_EQ(options().validate(), "");
  InputPairingOptions o = options();
  o.altitude_topic = false;
  EXPECT_NE(o.validate().find("fixed_altitude_m"), std::string::npos);
  o = options();
  o.sync_max_interval_s = 0.0;
  EXPECT_NE(o.validate().find("sync_max_interval_s"), std::string::npos);
  o = options();
  o.fallback_altitude_m = -1.0;
  EXPECT_NE(o.validate().find("fallback_altitude_m"), std::string::npos);
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
