// CounterStatus: counters as key/values, WARN while drops or skips grow (no master needed).
#include <gtest/gtest.h>

#include <diagnostic_msgs/DiagnosticStatus.h>

#include "uw_multislam/ros/diagnostics.h"

namespace uw_multislam {
namespace {

using diagnostic_msgs::DiagnosticStatus;
namespace rd = ros_diagnostics;

std::string value(const diagnostic_updater::DiagnosticStatusWrapper& s, const std::string& key) {
  for (const auto& kv : s.values) {
    if (kv.key == key) return kv.value;
  }
  return "<missing>";
}

TEST(Diagnostics, OkWhileOnlyPlainCountersGrow) {
  rd::CounterStatus status(10.0);
  diagnostic_updater::DiagnosticStatusWrapper s;
  status.fill(s, {{"frames", 3}, {"dropped", 0, true}, {"ms_per_frame", 41.25}}, 0.0);
  EXPECT_EQ(s.level, DiagnosticStatus::OK);
  ASSERT_EQ(s.values.size(), 3u);
  EXPECT_EQ(value(s, "frames"), "3");
  EXPECT_EQ(value(s, "ms_per_frame"), "41.250");
  diagnostic_updater::DiagnosticStatusWrapper t;
  status.fill(t, {{"frames", 300}, {"dropped", 0, true}, {"ms_per_frame", 40.0}}, 5.0);
  EXPECT_EQ(t.level, DiagnosticStatus::OK);
}

TEST(Diagnostics, WarnWhileAWatchedCounterGrowsThenOkAgain) {
  rd::CounterStatus status(10.0);
  diagnostic_updater::DiagnosticStatusWrapper a, b, c, d;
  status.fill(a, {{"frames", 1}, {"dropped", 0, true}, {"skipped_empty_image", 0, true}}, 0.0);
  EXPECT_EQ(a.level, DiagnosticStatus::OK);
  status.fill(b, {{"frames", 5}, {"dropped", 2, true}, {"skipped_empty_image", 1, true}}, 1.0);
  EXPECT_EQ(b.level, DiagnosticStatus::WARN);
  EXPECT_NE(b.message.find("dropped +2"), std::string::npos) << b.message;
  EXPECT_NE(b.message.find("skipped_empty_image +1"), std::string::npos) << b.message;
  status.fill(c, {{"frames", 9}, {"dropped", 2, true}, {"skipped_empty_image", 1, true}}, 10.5);
  EXPECT_EQ(c.level, DiagnosticStatus::WARN) << "held for 10 s";
  status.fill(d, {{"frames", 12}, {"dropped", 2, true}, {"skipped_empty_image", 1, true}}, 11.5);
  EXPECT_EQ(d.level, DiagnosticStatus::OK) << d.message;
  EXPECT_EQ(value(d, "dropped"), "2");
}

TEST(Diagnostics, ProblemAndErrorOverrideTheCounters) {
  rd::CounterStatus status;
  diagnostic_updater::DiagnosticStatusWrapper w, e;
  status.fill(w, {{"frames", 0}}, 0.0, "no altitude on /altitude for 6 s");
  EXPECT_EQ(w.level, DiagnosticStatus::WARN);
  EXPECT_EQ(w.message, "no altitude on /altitude for 6 s");
  status.fill(e, {{"frames", 0}}, 1.0, "a problem", "an error");
  EXPECT_EQ(e.level, DiagnosticStatus::ERROR);
  EXPECT_EQ(e.message, "an error");
}

TEST(Diagnostics, ACounterAlreadyNonZeroAtTheFirstReportWarns) {
  rd::CounterStatus status(10.0);
  diagnostic_updater::DiagnosticStatusWrapper s;
  status.fill(s, {{"dropped", 4, true}}, 100.0);
  EXPECT_EQ(s.level, DiagnosticStatus::WARN);
}

TEST(Diagnostics, CountersLine) {
  EXPECT_EQ(ros_diagnostics::countersLine("counters so far:", {{"frames", 12}, {"rate_hz", 2.5}, {"drops", 0, true}}),
            "counters so far: frames 12 rate_hz 2.500 drops 0");
}

}  // namespace
}  // namespace uw_multislam
