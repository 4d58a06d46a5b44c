// CounterStatus: counters as key/values, WARN while drops or skips grow (no master needed).
#include <gtest/gtest.h>

#include <diagnostic_msgs/DiagnosticStatus.h>

#include <fstream>
#include <map>
#include <regex>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "uw_multislam/core/session/session_manager.h"
#include "uw_multislam/core/session/session_worker.h"
#include "uw_multislam/ros/backend_counters.h"
#include "uw_multislam/ros/diagnostics.h"
#include "uw_multislam/ros/fleet_hash_exchange.h"
#include "uw_multislam/ros/fleet_peer_client.h"
#include "uw_multislam/ros/frame_publisher.h"
#include "uw_multislam/ros/live_mosaic_publisher.h"
#include "uw_multislam/ros/loop_detector_counters.h"
#include "uw_multislam/ros/odometry_counters.h"

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

// A counter table: each field under its key, in order, with its flag; a key twice is refused.
struct Sample {
  long frames = 0, drops = 0;
  double ms = 0.0;
};

TEST(CounterTable, GivesEachFieldUnderItsKeyInOrder) {
  const rd::CounterTable<Sample> table = {{"frames", &Sample::frames, "frames seen"},
                                          {"drops", &Sample::drops, "frames dropped", true},
                                          {"ms", &Sample::ms, "time, ms"}};
  Sample s;
  s.frames = 7, s.drops = 2, s.ms = 1.5;
  const std::vector<rd::Counter> c = table.counters(s);
  ASSERT_EQ(c.size(), 3u);
  EXPECT_EQ(c[0].key, "frames");
  EXPECT_EQ(c[0].value, 7.0);
  EXPECT_FALSE(c[0].warn_on_growth);
  EXPECT_EQ(c[1].key, "drops");
  EXPECT_EQ(c[1].value, 2.0);
  EXPECT_TRUE(c[1].warn_on_growth);
  EXPECT_EQ(c[2].value, 1.5);
  EXPECT_EQ(table.specs()[1].help, "frames dropped");
  EXPECT_EQ(rd::countersLine("counters at shutdown:", c), "counters at shutdown: frames 7 drops 2 ms 1.500");
  EXPECT_THROW((rd::CounterTable<Sample>{{"frames", &Sample::frames, "a"}, {"frames", &Sample::drops, "b"}}),
               std::logic_error);
  EXPECT_THROW((rd::CounterTable<Sample>{{"frames", &Sample::frames, ""}}), std::logic_error);
}

// doc/diagnostics.md against the counter tables: one markdown table per nodelet section
// ("## odometry"), rows "| `key` | meaning | WARN |".
struct DocRow {
  std::string help;
  bool warn = false;
};

std::map<std::string, DocRow> documented(const std::string& section) {
  std::ifstream in(std::string(UWMS_SOURCE_DIR) + "/doc/diagnostics.md");
  if (!in) throw std::runtime_error("doc/diagnostics.md not found under " UWMS_SOURCE_DIR);
  std::map<std::string, DocRow> rows;
  const std::regex row(R"(^\| `([a-zA-Z0-9_]+)` \| (.*) \| (WARN)? *\|$)");
  std::string line;
  bool inside = false;
  while (std::getline(in, line)) {
    if (line.rfind("## ", 0) == 0) inside = line == "## " + section;
    std::smatch m;
    if (!inside || !std::regex_match(line, m, row)) continue;
    EXPECT_TRUE(rows.emplace(m[1], DocRow{m[2], m[3].matched}).second) << section << ": " << m[1] << " twice";
  }
  return rows;
}

void expectDocumented(const std::string& section, const std::vector<rd::CounterSpec>& specs) {
  std::map<std::string, DocRow> doc = documented(section);
  EXPECT_FALSE(doc.empty()) << "no table in section " << section;
  for (const rd::CounterSpec& s : specs) {
    const auto found = doc.find(s.key);
    if (found == doc.end()) {
      ADD_FAILURE() << section << ": key " << s.key << " is not documented in doc/diagnostics.md";
      continue;
    }
    EXPECT_EQ(found->second.help, s.help) << section << ": " << s.key;
    EXPECT_EQ(found->second.warn, s.warn_on_growth) << section << ": " << s.key << " WARN flag";
    doc.erase(found);
  }
  for (const auto& extra : doc) ADD_FAILURE() << section << ": " << extra.first << " is documented but not a counter";
}

TEST(DiagnosticsDoc, TheOdometrysCountersAreDocumentedAsTheCodeDeclaresThem) {
  expectDocumented("odometry", rd::odometryCounterTable().specs());
}

TEST(DiagnosticsDoc, TheLoopDetectorsCountersAreDocumentedAsTheCodeDeclaresThem) {
  expectDocumented("loop_detector", rd::loopDetectorCounterTable().specs());
}

TEST(DiagnosticsDoc, TheBackEndsCountersAreDocumentedAsTheCodeDeclaresThem) {
  expectDocumented("backend", rd::backendCounterTable().specs());
  expectDocumented("backend, with fleet/vehicle", rd::fleetCounterTable().specs());
}

// The back-end's counters from its parts' stats: each input field a distinct value, so that one
// wired to the wrong key (or not at all) shows.
std::map<std::string, double> byKey(const std::vector<rd::Counter>& counters) {
  std::map<std::string, double> out;
  for (const rd::Counter& c : counters) out[c.key] = c.value;
  return out;
}

TEST(BackendCounters, WorkerFramesAndMosaicStatsLandUnderTheirKeys) {
  core::SessionWorkerStats w;
  w.keyframes = 11, w.loops = 12, w.waiting = 13, w.waiting_dropped = 14, w.dropped_queue_full = 15;
  w.queued = 16, w.skipped = 17;
  core::HandoverStats h;
  h.subscribers = 21, h.total = 22, h.sent = 23, h.seconds = 2.5;
  ros_frames::FrameStats f;
  f.map_to_odom_published = 31, f.odom_lookup_failures = 32, f.map_to_odom_rate_hz = 3.5;
  ros_mosaic::MosaicStats m;
  m.published = 41, m.drawn = 42, m.missing = 43, m.ms = 4.5, m.resolution_m = 0.25, m.images_kB = 46.5;
  rd::BackendCounters c;
  rd::setWorkerCounters(w, h, 100, 200, &c);  // 100 keyframes and 200 loops refused before the worker
  rd::setFrameCounters(f, &c);
  rd::setMosaicCounters(m, &c);
  const std::map<std::string, double> v = byKey(rd::backendCounterTable().counters(c));
  const std::map<std::string, double> expected = {{"keyframes_received", 111},
                                                  {"loops_received", 212},
                                                  {"loops_waiting", 13},
                                                  {"loops_dropped_waiting", 14},
                                                  {"dropped_queue_full", 15},
                                                  {"queue_length", 16},
                                                  {"bad_messages", 317},
                                                  {"handover_subscribers", 21},
                                                  {"handover_keyframes_total", 22},
                                                  {"handover_keyframes_sent", 23},
                                                  {"handover_s", 2.5},
                                                  {"map_to_odom_published", 31},
                                                  {"odom_lookup_failures", 32},
                                                  {"map_to_odom_rate_hz", 3.5},
                                                  {"mosaic_published", 41},
                                                  {"mosaic_keyframes_drawn", 42},
                                                  {"mosaic_keyframes_missing", 43},
                                                  {"mosaic_draw_ms", 4.5},
                                                  {"mosaic_resolution_m", 0.25},
                                                  {"mosaic_images_kB", 46.5}};
  for (const auto& [key, value] : expected) {
    ASSERT_TRUE(v.count(key)) << key;
    EXPECT_EQ(v.at(key), value) << key;
  }
}

TEST(BackendCounters, FleetStatsLandUnderTheirKeys) {
  ros_fleet::HashExchangeStats x;
  x.hashes_sent = 1, x.hash_bytes_sent = 2, x.hashes_received = 3, x.hash_bytes_received = 4, x.refused = 5;
  x.sessions_ended = 6;
  ros_fleet::PeerStats p;
  p.requested = 7, p.bytes_received = 8, p.failures = 9, p.timeouts = 10;
  const std::vector<rd::Counter> c = rd::fleetCounters(x, p);
  const std::vector<std::string> keys = {
      "fleet_hashes_sent",      "fleet_hash_bytes_sent", "fleet_hashes_received",    "fleet_hash_bytes_received",
      "fleet_refused",          "fleet_sessions_ended",  "fleet_features_requested", "fleet_feature_bytes_received",
      "fleet_feature_failures", "fleet_feature_timeouts"};
  ASSERT_EQ(c.size(), keys.size());
  for (std::size_t i = 0; i < keys.size(); ++i) {
    EXPECT_EQ(c[i].key, keys[i]);
    EXPECT_EQ(c[i].value, static_cast<double>(i + 1)) << keys[i];
  }
}

TEST(BackendCounters, StatusValuesBesideTheCounters) {
  diagnostic_updater::DiagnosticStatusWrapper s;
  core::SessionManager manager{core::SessionManagerOptions()};  // no store, mapping
  core::RelocalisationTracker::State r;
  r.session = 3, r.map = 1, r.loops = 4, r.published = 5;
  rd::addBackendValues(s, manager.view(), "gtsam", "/tmp/x.db", r);
  EXPECT_EQ(value(s, "optimizer"), "gtsam");
  EXPECT_EQ(value(s, "store"), "none");
  EXPECT_EQ(value(s, "mode"), "mapping");
  EXPECT_EQ(value(s, "relocalised"), "session 3 in map 1");
  diagnostic_updater::DiagnosticStatusWrapper t;
  rd::addBackendValues(t, manager.view(), "gtsam", "/tmp/x.db", core::RelocalisationTracker::State());
  EXPECT_EQ(value(t, "relocalised"), "no");
  rd::BackendCounters c;
  rd::setRelocalisationCounters(r, &c);
  const std::map<std::string, double> v = byKey(rd::backendCounterTable().counters(c));
  EXPECT_EQ(v.at("relocalised_map"), 1);
  EXPECT_EQ(v.at("relocalised_loops"), 4);
  EXPECT_EQ(v.at("relocalised_poses_published"), 5);
}

}  // namespace
}  // namespace uw_multislam
