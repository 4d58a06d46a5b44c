// AltitudeBuffer: the altitude at an image stamp from a slower altimeter.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <stdexcept>

#include "uw_multislam/core/frontend/altitude_buffer.h"

namespace uw_multislam {
namespace core {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

AltitudeBufferOptions options(double max_age_s = 1.0, double reorder_tolerance_s = 1.0, std::size_t capacity = 1000) {
  AltitudeBufferOptions o;
  o.max_age_s = max_age_s;
  o.reorder_tolerance_s = reorder_tolerance_s;
  o.capacity = capacity;
  return o;
}

TEST(AltitudeBuffer, InterpolatesLinearlyBetweenTheReadingsAroundTheStamp) {
  AltitudeBuffer b(options(1.0, 5.0));
  // A 2 Hz altimeter on a linear descent 2.0 m -> 1.0 m over 2 s, and a 10 Hz camera.
  for (int k = 0; k <= 4; ++k) b.add(100.0 + 0.5 * k, 2.0 - 0.25 * k);
  for (int i = 0; i <= 20; ++i) {
    const double t = 100.0 + i / 10.0;
    const AltitudeAt a = b.at(t);
    ASSERT_TRUE(a.ok()) << t << " " << altitudeStatusName(a.status);
    EXPECT_NEAR(a.altitude_m, 2.0 - 0.5 * (t - 100.0), 1e-12) << t;  // exact on a linear profile
    EXPECT_LE(a.age_s, 0.25 + 1e-12);
  }
  EXPECT_EQ(b.at(100.5).status, AltitudeStatus::kExact);
  EXPECT_DOUBLE_EQ(b.at(100.5).altitude_m, 1.75);
  EXPECT_DOUBLE_EQ(b.at(100.5).age_s, 0.0);
  const AltitudeAt mid = b.at(100.6);
  EXPECT_EQ(mid.status, AltitudeStatus::kInterpolated);
  EXPECT_NEAR(mid.age_s, 0.1, 1e-12);
  // Non-linear readings: the weights are the stamp's position between the two readings.
  AltitudeBuffer c(options());
  c.add(10.0, 3.0);
  c.add(10.4, 5.0);
  EXPECT_NEAR(c.at(10.1).altitude_m, 3.5, 1e-12);
  EXPECT_NEAR(c.at(10.3).altitude_m, 4.5, 1e-12);
}

TEST(AltitudeBuffer, WaitsForTheReadingAfterTheStampThenUsesTheLastWithinTheAgeBound) {
  AltitudeBuffer b(options(1.0));
  EXPECT_EQ(b.at(5.0).status, AltitudeStatus::kPending) << "no reading yet";
  EXPECT_EQ(b.at(5.0, true).status, AltitudeStatus::kStale);
  b.add(5.0, 2.0);
  EXPECT_EQ(b.at(5.3).status, AltitudeStatus::kPending) << "the next reading may still come";
  const AltitudeAt last = b.at(5.3, true);
  EXPECT_EQ(last.status, AltitudeStatus::kNearest);
  EXPECT_DOUBLE_EQ(last.altitude_m, 2.0);
  EXPECT_NEAR(last.age_s, 0.3, 1e-12);
  EXPECT_EQ(b.at(6.0, true).status, AltitudeStatus::kNearest) << "the bound is inclusive";
  EXPECT_EQ(b.at(6.01, true).status, AltitudeStatus::kStale);
  EXPECT_TRUE(std::isnan(b.at(6.01, true).altitude_m));
  // Before the first reading: the first one within the bound.
  EXPECT_EQ(b.at(4.5).status, AltitudeStatus::kNearest);
  EXPECT_EQ(b.at(3.9).status, AltitudeStatus::kPending) << "more than reorder_tolerance_s behind the altimeter";
  EXPECT_EQ(b.at(3.9, true).status, AltitudeStatus::kStale);
  b.add(5.5, 3.0);
  EXPECT_EQ(b.at(5.3).status, AltitudeStatus::kInterpolated);
  EXPECT_NEAR(b.at(5.3).altitude_m, 2.6, 1e-12);
}

TEST(AltitudeBuffer, AGapLongerThanTheAgeBoundIsNotInterpolated) {
  AltitudeBuffer b(options(1.0, 5.0));
  b.add(10.0, 2.0);
  b.add(13.0, 4.0);  // the altimeter was silent for 3 s
  EXPECT_EQ(b.at(10.4).status, AltitudeStatus::kNearest);
  EXPECT_DOUBLE_EQ(b.at(10.4).altitude_m, 2.0);
  EXPECT_EQ(b.at(12.2).status, AltitudeStatus::kNearest);
  EXPECT_DOUBLE_EQ(b.at(12.2).altitude_m, 4.0);
  EXPECT_EQ(b.at(11.5).status, AltitudeStatus::kStale) << "1.5 s from either reading";
  b.add(11.0, 3.0);
  EXPECT_EQ(b.at(10.5).status, AltitudeStatus::kInterpolated) << "a gap of exactly max_age_s is interpolated";
  EXPECT_NEAR(b.at(10.5).altitude_m, 2.5, 1e-12);
}

TEST(AltitudeBuffer, OutOfOrderReadingsAreInsertedInOrderAndDuplicatesReplace) {
  AltitudeBuffer b(options(1.0, 1.0));
  EXPECT_EQ(b.add(1.0, 2.0), AltitudeBuffer::AddResult::kAdded);
  EXPECT_EQ(b.add(2.0, 4.0), AltitudeBuffer::AddResult::kAdded);
  EXPECT_EQ(b.add(1.5, 10.0), AltitudeBuffer::AddResult::kAdded);  // late by 0.5 s
  EXPECT_EQ(b.size(), 3u);
  EXPECT_DOUBLE_EQ(b.newest(), 2.0);
  EXPECT_NEAR(b.at(1.25).altitude_m, 6.0, 1e-12);
  EXPECT_NEAR(b.at(1.75).altitude_m, 7.0, 1e-12);
  EXPECT_EQ(b.add(1.5, 3.0), AltitudeBuffer::AddResult::kReplaced);
  EXPECT_EQ(b.size(), 3u);
  EXPECT_NEAR(b.at(1.25).altitude_m, 2.5, 1e-12);
  EXPECT_EQ(b.add(kNaN, 3.0), AltitudeBuffer::AddResult::kRefused);
  EXPECT_EQ(b.size(), 3u);
}

TEST(AltitudeBuffer, InvalidReadingsMakeTheAnswersThatUseThemInvalid) {
  AltitudeBuffer b(options(1.0, 10.0));
  b.add(1.0, 2.0);
  b.add(1.5, kNaN);
  b.add(2.0, -1.0);
  b.add(2.5, 2.2);
  b.add(3.0, 2.4);
  EXPECT_EQ(b.at(1.5).status, AltitudeStatus::kInvalid);
  EXPECT_TRUE(std::isnan(b.at(1.5).altitude_m));
  EXPECT_EQ(b.at(1.2).status, AltitudeStatus::kInvalid) << "interpolated with the NaN reading";
  EXPECT_EQ(b.at(2.2).status, AltitudeStatus::kInvalid) << "interpolated with the negative reading";
  EXPECT_EQ(b.at(2.7).status, AltitudeStatus::kInterpolated);
  EXPECT_NEAR(b.at(2.7).altitude_m, 2.28, 1e-12);
  b.add(3.5, std::numeric_limits<double>::infinity());
  EXPECT_EQ(b.at(3.6, true).status, AltitudeStatus::kInvalid) << "the last reading alone, invalid";
  EXPECT_EQ(b.at(1.0).status, AltitudeStatus::kExact);
}

TEST(AltitudeBuffer, AStampJumpingBackClearsTheBuffer) {
  AltitudeBuffer b(options(1.0, 1.0));
  for (int k = 0; k < 20; ++k) b.add(100.0 + 0.5 * k, 2.0);
  // The camera loops first: its stamp is far behind the altimeter's, so the answer waits.
  EXPECT_EQ(b.at(100.2).status, AltitudeStatus::kPending);
  EXPECT_EQ(b.at(100.2, true).status, AltitudeStatus::kInterpolated) << "the old readings, once forced";
  EXPECT_EQ(b.add(100.0, 3.0), AltitudeBuffer::AddResult::kCleared);  // the bag loops
  EXPECT_EQ(b.size(), 1u);
  EXPECT_DOUBLE_EQ(b.newest(), 100.0);
  b.add(100.5, 3.5);
  EXPECT_NEAR(b.at(100.2).altitude_m, 3.2, 1e-12) << "only the new pass's readings";
  // Within the reorder tolerance a reading is late, not a loop.
  EXPECT_EQ(b.add(99.6, 2.0), AltitudeBuffer::AddResult::kAdded);
  EXPECT_EQ(b.size(), 3u);
}

TEST(AltitudeBuffer, MemoryIsBounded) {
  AltitudeBuffer b(options(1.0, 1.0, 50));
  for (int k = 0; k < 10000; ++k) {
    b.add(0.01 * k, 1.0 + 0.001 * k);
    ASSERT_LE(b.size(), 50u);
  }
  EXPECT_EQ(b.size(), 50u);
  EXPECT_DOUBLE_EQ(b.newest(), 99.99);
  EXPECT_TRUE(b.at(99.985).ok());
  EXPECT_NEAR(b.at(99.985).altitude_m, 1.0 + 0.001 * 9998.5, 1e-9);
  // A late reading older than everything kept, into a full buffer: kept only if newer than the oldest.
  b.add(99.0, 5.0);
  EXPECT_EQ(b.size(), 50u);
  b.clear();
  EXPECT_TRUE(b.empty());
}

TEST(AltitudeBuffer, RefusesBadOptions) {
  EXPECT_THROW(AltitudeBuffer(options(0.0)), std::invalid_argument);
  EXPECT_THROW(AltitudeBuffer(options(kNaN)), std::invalid_argument);
  EXPECT_THROW(AltitudeBuffer(options(1.0, -1.0)), std::invalid_argument);
  EXPECT_THROW(AltitudeBuffer(options(1.0, 1.0, 1)), std::invalid_argument);
  EXPECT_NE(options(0.0).validate().find("max_age_s"), std::string::npos);
  EXPECT_EQ(options().validate(), "");
  EXPECT_EQ(altitudeStatusName(AltitudeStatus::kInterpolated), "interpolated");
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
