// The session store (core/store/session_store.h): round trip into the back-end and the loop detector,
// bad files refused without being modified, a full disk, kill -9 during writing.
#include <gtest/gtest.h>
#include <sqlite3.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>
#include <cstring>
#include <limits>

#include <algorithm>
#include <csignal>
#include <fstream>
#include <iterator>
#include <map>
#include <random>

#include "../../common/fixtures.h"
#include "../../common/scoped_temp_dir.h"
#include "../../common/sql_file.h"
#include "uw_multislam/core/loops/loop_detector.h"
#include "uw_multislam/core/store/interrupted_run.h"
#include "uw_multislam/core/store/map_persistence.h"
#include "uw_multislam/core/store/session_store.h"

namespace uw_multislam {
namespace core {
namespace {

using testing_util::ScopedTempDir;

std::string readBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

void writeBytes(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out << bytes;
}

Eigen::Matrix3d diag(double sxy, double syaw) {
  return Eigen::Vector3d(sxy * sxy, sxy * sxy, syaw * syaw).asDiagonal();
}

using testing_util::camera320;

// A keyframe with random features (n points) and a random hash.
StoredKeyframe randomKeyframe(std::int64_t session, int k, int n, std::mt19937* rng) {
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  StoredKeyframe kf;
  kf.session = session;
  kf.keyframe = k;
  kf.frame_index = 3 * k + 1;
  kf.stamp_s = 0.25 * k;
  kf.altitude_m = 2.0 + 0.01 * k;
  kf.image_size = cv::Size(320, 240);
  for (int i = 0; i < n; ++i) kf.points.emplace_back(320 * u(*rng), 240 * u(*rng));
  kf.descriptors = cv::Mat(n, 128, CV_8U);
  cv::randu(kf.descriptors, 0, 256);
  kf.hash = Eigen::VectorXf(HalocProjections::kHashSize);
  for (int i = 0; i < kf.hash.size(); ++i) kf.hash[i] = 0.2f * u(*rng) - 0.05f;
  kf.thumbnail = {0xff, 0xd8, 0xff, 0xd9};
  return kf;
}

// Records sessions into a back-end and a store the way offline_slam does.
struct Recorder {
  Recorder(SessionStore* st, MultiSessionBackend* b) : store(st), backend(b) {}
  SessionStore* store;
  MultiSessionBackend* backend;
  std::vector<std::int64_t> session_ids, loop_ids;
  std::mt19937 rng{5};

  int start(const std::string& name) {
    const int s = backend->startSession(name);
    session_ids.push_back(store->addSession(name, camera320(), 0.0));
    StoredKeyframe kf = randomKeyframe(session_ids[s], 0, 20, &rng);
    store->addKeyframe(kf, nullptr, nullptr);
    return s;
  }
  void step(int s, const Pose2& m, const std::vector<BackendLoop>& loops = {}) {
    const UncertainPose2 motion(m, diag(0.02, 0.01));
    backend->addMotion(s, motion);
    const int k = backend->session(s).keyframes - 1;
    std::vector<StoredLoop> stored;
    for (const BackendLoop& l : loops) {
      StoredLoop sl;
      sl.session_a = session_ids[l.session_a];
      sl.keyframe_a = l.keyframe_a;
      sl.session_b = session_ids[l.session_b];
      sl.keyframe_b = l.keyframe_b;
      sl.global = l.session_a != l.session_b;
      sl.inliers = 40;
      sl.z = l.z;
      stored.push_back(sl);
    }
    StoredKeyframe kf = randomKeyframe(session_ids[s], k, 20, &rng);
    store->addKeyframe(kf, &motion, &stored);
    for (std::size_t i = 0; i < loops.size(); ++i) {
      backend->addLoop(loops[i]);
      loop_ids.push_back(stored[i].id);
    }
  }
  void end(int s) {
    backend->endSession(s);
    store->endSession(session_ids[s], 1.0);
    saveBackendMaps(store, *backend, session_ids, loop_ids);
  }
};

// Truth: session 0 a line along x, session 1 a parallel line 1 m beside it, going back; session
// 2 along the first one again.
Pose2 truth(int s, int k) {
  if (s == 0) return Pose2(0.5 * k, 0.0, 0.0);
  if (s == 1) return Pose2(6.0 - 0.5 * k, 1.0, M_PI);
  return Pose2(0.5 * k + 0.2, 0.1, 0.05);
}

BackendLoop truthLoop(int sa, int ka, int sb, int kb, double err) {
  return {
      sa, ka, sb, kb,
      UncertainPose2(compose(between(truth(sa, ka), truth(sb, kb)), Pose2(err, -err, 0.01 * err)), diag(0.01, 0.005))};
}

// The back-end's options for recordMission: its loops carry no inlier count, so session 1 joins
// session 0 by the count rule (K = 5 loops), not by join_policy consistent (the default), whose
// join_min_inliers they never reach.
BackendOptions missionOptions() {
  BackendOptions o;
  o.join_policy = JoinPolicy::kCount;
  return o;
}

// Three sessions: 1 joined to 0 by five global loops, 2 joined by an explicit join and split
// off again, intra-session loops; noisy odometry so that optimisation moves things.
void recordMission(Recorder* r) {
  std::mt19937 rng(11);
  std::normal_distribution<double> n(0.0, 0.02);
  auto noisy = [&](int s, int k) {
    const Pose2 m = between(truth(s, k - 1), truth(s, k));
    return Pose2(m.x() + n(rng), m.y() + n(rng), m.yaw() + 0.5 * n(rng));
  };
  const int s0 = r->start("a");
  for (int k = 1; k < 13; ++k)
    r->step(s0, noisy(0, k),
            k == 12 ? std::vector<BackendLoop>{truthLoop(0, 2, 0, 12, 0.01)} : std::vector<BackendLoop>{});
  r->end(s0);
  const int s1 = r->start("b");
  for (int k = 1; k < 12; ++k) {
    std::vector<BackendLoop> loops;
    if (k >= 3 && k <= 7) loops.push_back(truthLoop(0, 12 - k, 1, k, 0.002 * k));
    r->step(s1, noisy(1, k), loops);
  }
  r->end(s1);
  const int s2 = r->start("c");
  for (int k = 1; k < 8; ++k)
    r->step(s2, noisy(2, k),
            k == 4 ? std::vector<BackendLoop>{truthLoop(0, 3, 2, 4, 0.0)} : std::vector<BackendLoop>{});
  r->end(s2);
  ASSERT_TRUE(r->backend->join(0, 2, 1).ok());
  saveBackendMaps(r->store, *r->backend, r->session_ids, r->loop_ids);
  ASSERT_TRUE(r->backend->split(2).ok());
  saveBackendMaps(r->store, *r->backend, r->session_ids, r->loop_ids);
}

void expectSameBackends(const MultiSessionBackend& a, const MultiSessionBackend& b) {
  ASSERT_EQ(a.numSessions(), b.numSessions());
  ASSERT_EQ(a.mapIds(), b.mapIds());
  for (int s = 0; s < a.numSessions(); ++s) {
    EXPECT_EQ(a.session(s).name, b.session(s).name);
    EXPECT_EQ(a.mapOf(s), b.mapOf(s));
    const auto pa = a.sessionPoses(s), pb = b.sessionPoses(s);
    ASSERT_EQ(pa.size(), pb.size());
    for (std::size_t k = 0; k < pa.size(); ++k) {
      EXPECT_NEAR(pa[k].x(), pb[k].x(), 1e-12) << "session " << s << " keyframe " << k;
      EXPECT_NEAR(pa[k].y(), pb[k].y(), 1e-12);
      EXPECT_NEAR(pa[k].yaw(), pb[k].yaw(), 1e-12);
    }
  }
  for (int m : a.mapIds()) {
    EXPECT_EQ(a.chain(m), b.chain(m));
    const auto la = a.links(m), lb = b.links(m);
    ASSERT_EQ(la.size(), lb.size());
    for (std::size_t i = 0; i < la.size(); ++i) {
      EXPECT_EQ(la[i].previous, lb[i].previous);
      EXPECT_EQ(la[i].current, lb[i].current);
      EXPECT_EQ(la[i].loops, lb[i].loops);
      EXPECT_NEAR(la[i].estimate.x(), lb[i].estimate.x(), 1e-12);
      EXPECT_NEAR(la[i].measured.mean.yaw(), lb[i].measured.mean.yaw(), 1e-12);
      EXPECT_TRUE(la[i].measured.covariance.isApprox(lb[i].measured.covariance, 1e-12));
    }
  }
  ASSERT_EQ(a.numLoops(), b.numLoops());
  for (int id = 0; id < a.numLoops(); ++id) {
    const LoopRecord x = a.loopRecord(id), y = b.loopRecord(id);
    EXPECT_EQ(x.loop.session_a, y.loop.session_a);
    EXPECT_EQ(x.loop.keyframe_b, y.loop.keyframe_b);
    EXPECT_EQ(x.summarised, y.summarised) << "loop " << id;
    EXPECT_EQ(x.refused, y.refused);
    EXPECT_EQ(x.applied, y.applied);
    EXPECT_EQ(x.loop.z.mean.x(), y.loop.z.mean.x());
  }
  EXPECT_EQ(a.splitPairs(), b.splitPairs());
}

class StoreBothOptimizers : public ::testing::TestWithParam<OptimizerKind> {};

TEST_P(StoreBothOptimizers, RoundTripGivesIdenticalTrajectoriesLoopsAndMaps) {
  ScopedTempDir dir("uwms_store");
  const std::string path = (dir.path() / "maps.db").string();
  BackendOptions opt = missionOptions();
  opt.optimizer = GetParam();
  opt.optimise_every = 1;
  MultiSessionBackend original(opt);
  {
    SessionStore store(path);
    Recorder r(&store, &original);
    recordMission(&r);
    ASSERT_EQ(original.mapOf(1), 0) << "the five global loops should have joined session 1 to 0";
    ASSERT_EQ(original.mapOf(2), 2) << "session 2 was split off";
  }
  SessionStore store(path);
  MultiSessionBackend restored(opt);
  LoopOptions lo;
  LoopDetector detector(lo, MatchOptions(), RansacOptions(), 20);
  std::vector<std::unique_ptr<CameraIntrinsics>> cameras;
  const RestoredStore rs = restoreStore(store, &restored, &detector, &cameras);
  expectSameBackends(original, restored);
  EXPECT_EQ(rs.keyframes, 13 + 12 + 8);
  EXPECT_EQ(detector.size(), 33u);
  EXPECT_EQ(rs.frame_of_keyframe[1][4], 13);
  EXPECT_EQ(store.sessions()[2].name, "c");
  EXPECT_EQ(store.sessions()[2].state, StoredSessionState::kFinished);
  EXPECT_EQ(store.keyframes(store.sessions()[1].id)[3].thumbnail.size(), 4u);

  // The restored back-end goes on like the original: a new session, joined from loops.
  for (MultiSessionBackend* b : {&original, &restored}) {
    const int s = b->startSession("d");
    EXPECT_EQ(s, 3);
    for (int k = 1; k < 6; ++k) b->addMotion(s, UncertainPose2(Pose2(0.5, 0, 0), diag(0.02, 0.01)));
    for (int k = 0; k < 5; ++k) b->addLoop({0, k + 1, s, k, UncertainPose2(Pose2(0, 0.1, 0), diag(0.01, 0.005))});
    b->endSession(s);
  }
  expectSameBackends(original, restored);
}

// A session stored with a 0x0 camera (older stores, keyframe 0 lost) restores with its poses and no
// note (a note would make export refuse the store; SessionManager::reload says it instead).
TEST(Store, ASessionWithoutAStoredCameraRestoresWithItsPoses) {
  ScopedTempDir dir("uwms_store");
  const std::string path = (dir.path() / "maps.db").string();
  BackendOptions opt = missionOptions();
  MultiSessionBackend original(opt);
  {
    SessionStore store(path);
    Recorder r(&store, &original);
    recordMission(&r);
  }
  ASSERT_TRUE(testing_util::execSql(path,
                                    "UPDATE sessions SET cam_width = 0, cam_height = 0, cam_fx = 0, cam_fy = 0, "
                                    "cam_cx = 0, cam_cy = 0 WHERE name = 'b'"));
  SessionStore store(path);
  for (const bool with_detector : {false, true}) {
    MultiSessionBackend restored(opt);
    LoopDetector detector(LoopOptions(), MatchOptions(), RansacOptions(), 20);
    std::vector<std::unique_ptr<CameraIntrinsics>> cameras;
    const RestoredStore rs =
        restoreStore(store, &restored, with_detector ? &detector : nullptr, with_detector ? &cameras : nullptr);
    EXPECT_TRUE(rs.notes.empty()) << rs.notes.front();
    expectSameBackends(original, restored);
  }
}

INSTANTIATE_TEST_SUITE_P(Store, StoreBothOptimizers, ::testing::Values(OptimizerKind::kSparse, OptimizerKind::kIekf),
                         [](const auto& info) { return std::string(optimizerName(info.param)); });

// The mission recorded into `dir`/maps.db through `backend` (kept by the caller to compare with).
std::string recordStore(const ScopedTempDir& dir, MultiSessionBackend* backend) {
  const std::string path = (dir.path() / "maps.db").string();
  SessionStore store(path);
  Recorder r(&store, backend);
  recordMission(&r);
  return path;
}

TEST(Store, DamagedMapMotionsAreRebuiltFromTheSessionsNotRestoredAsNaN) {
  ScopedTempDir dir("uwms_store");
  BackendOptions opt = missionOptions();
  opt.optimise_every = 1;
  MultiSessionBackend original(opt);
  const std::string path = recordStore(dir, &original);
  ASSERT_EQ(original.mapOf(1), 0);
  // One NaN in the stored motions of the map of sessions 0 and 1 (a bad page, an older build).
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
  sqlite3_stmt* st = nullptr;
  ASSERT_EQ(sqlite3_prepare_v2(db, "SELECT id, motions FROM maps ORDER BY id LIMIT 1", -1, &st, nullptr), SQLITE_OK);
  ASSERT_EQ(sqlite3_step(st), SQLITE_ROW);
  const std::int64_t map_id = sqlite3_column_int64(st, 0);
  const auto* p = static_cast<const char*>(sqlite3_column_blob(st, 1));
  std::string blob(p, p + sqlite3_column_bytes(st, 1));
  sqlite3_finalize(st);
  ASSERT_GE(blob.size(), 16u);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  std::memcpy(&blob[8], &nan, sizeof nan);
  ASSERT_EQ(sqlite3_prepare_v2(db, "UPDATE maps SET motions = ? WHERE id = ?", -1, &st, nullptr), SQLITE_OK);
  sqlite3_bind_blob(st, 1, blob.data(), static_cast<int>(blob.size()), SQLITE_TRANSIENT);
  sqlite3_bind_int64(st, 2, map_id);
  ASSERT_EQ(sqlite3_step(st), SQLITE_DONE);
  sqlite3_finalize(st);
  sqlite3_close(db);

  SessionStore store(path);
  MultiSessionBackend restored(opt);
  const RestoredStore rs = restoreStore(store, &restored, nullptr, nullptr);
  ASSERT_EQ(rs.notes.size(), 1u);
  EXPECT_NE(rs.notes[0].find("stored motion 0 is damaged (mean not finite)"), std::string::npos) << rs.notes[0];
  EXPECT_EQ(restored.mapOf(1), 0);  // still joined: the links and loops are kept
  restored.flush();                 // optimised again from the sessions' odometry, links and loops
  double worst = 0.0;
  for (int s : {0, 1}) {
    const std::vector<Pose2> got = restored.sessionPoses(s), want = original.sessionPoses(s);
    ASSERT_EQ(got.size(), want.size());
    for (std::size_t k = 0; k < got.size(); ++k) {
      ASSERT_TRUE(got[k].isFinite()) << s << " " << k;
      worst = std::max(worst, (got[k].translation() - want[k].translation()).norm());
    }
  }
  EXPECT_LT(worst, 0.01) << "the rebuilt map is not the saved one";
  std::printf("damaged map motions rebuilt: worst keyframe %.6f m from the saved map\n", worst);
}

TEST(Store, AMapWithADamagedLinkOrNamingAMissingSessionIsNotedAndItsSessionsRestoredUnjoined) {
  ScopedTempDir dir("uwms_store");
  BackendOptions opt = missionOptions();
  MultiSessionBackend original(opt);
  const std::string path = recordStore(dir, &original);
  ASSERT_EQ(original.mapOf(1), 0);
  std::int64_t second = 0;
  {
    SessionStore store(path);
    second = store.sessions()[1].id;
  }
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
  const auto sql = [&](const std::string& statement) {
    ASSERT_EQ(sqlite3_exec(db, statement.c_str(), nullptr, nullptr, nullptr), SQLITE_OK) << statement;
  };
  // A session started and never given a keyframe, with the single-session map the back-end saves
  // for it: as always, left out without a word (not "damaged").
  sql("INSERT INTO sessions(id, name, state, start_stamp, end_stamp, cam_width, cam_height, cam_fx, cam_fy, cam_cx, "
      "cam_cy) VALUES (77, 'empty', 'finished', 0, 0, 0, 0, 0, 0, 0, 0)");
  sql("INSERT INTO maps(id, pending, motions) VALUES (77, 0, NULL)");
  sql("INSERT INTO map_sessions(map, position, session) VALUES (77, 0, 77)");
  {
    SessionStore store(path);
    MultiSessionBackend restored(opt);
    EXPECT_EQ(restoreStore(store, &restored, nullptr, nullptr).notes, std::vector<std::string>());
    EXPECT_EQ(restored.mapOf(1), 0);
  }
  const auto set_link_variance_x = [&](double v) {
    const std::vector<double> cov{v, 0, 0, 0, 1, 0, 0, 0, 1};
    sqlite3_stmt* st = nullptr;
    ASSERT_EQ(sqlite3_prepare_v2(db, "UPDATE links SET cov = ?", -1, &st, nullptr), SQLITE_OK);
    sqlite3_bind_blob(st, 1, cov.data(), static_cast<int>(cov.size() * sizeof(double)), SQLITE_TRANSIENT);
    ASSERT_EQ(sqlite3_step(st), SQLITE_DONE);
    sqlite3_finalize(st);
  };
  // The link joining sessions 0 and 1 with a negative variance: noted, both restored unjoined.
  set_link_variance_x(-1.0);
  {
    SessionStore store(path);
    MultiSessionBackend restored(opt);
    const RestoredStore rs = restoreStore(store, &restored, nullptr, nullptr);
    ASSERT_EQ(rs.notes.size(), 1u);
    EXPECT_NE(rs.notes[0].find("a link of the map of session"), std::string::npos) << rs.notes[0];
    EXPECT_NE(restored.mapOf(1), restored.mapOf(0));
    EXPECT_EQ(restored.numSessions(), 3);
    // The loops the damaged link summarised are pending again (summarised, every later join would
    // leave them out): the next global loop between the two sessions joins them again.
    EXPECT_GE(restored.pendingJoinLoops(0, 1), 5);
    int global = -1;
    for (int id = 0; id < restored.numLoops() && global < 0; ++id)
      if (restored.loopRecord(id).loop.session_a != restored.loopRecord(id).loop.session_b) global = id;
    ASSERT_GE(global, 0);
    restored.addLoop(restored.loopRecord(global).loop);  // the same place seen again
    EXPECT_EQ(restored.mapOf(1), restored.mapOf(0)) << "the sessions stay apart for good";
  }
  // The map names a session the store does not hold at all.
  set_link_variance_x(1.0);
  sql("UPDATE map_sessions SET session = 999 WHERE session = " + std::to_string(second));
  sqlite3_close(db);
  SessionStore store(path);
  MultiSessionBackend restored(opt);
  const RestoredStore rs = restoreStore(store, &restored, nullptr, nullptr);
  ASSERT_EQ(rs.notes.size(), 1u);
  EXPECT_NE(rs.notes[0].find("names session 999, which the store does not hold"), std::string::npos) << rs.notes[0];
  EXPECT_NE(restored.mapOf(1), restored.mapOf(0));
}

TEST(Store, KeyframeFeaturesComeBackExactly) {
  ScopedTempDir dir("uwms_store");
  const std::string path = (dir.path() / "maps.db").string();
  std::mt19937 rng(2);
  StoredKeyframe kf = randomKeyframe(0, 0, 500, &rng);
  {
    SessionStore store(path);
    kf.session = store.addSession("s", camera320(), 10.0);
    store.addKeyframe(kf, nullptr, nullptr);
  }
  SessionStore store(path);
  const auto back = store.keyframes(kf.session);
  ASSERT_EQ(back.size(), 1u);
  EXPECT_EQ(back[0].points, kf.points);
  EXPECT_EQ(cv::norm(back[0].descriptors, kf.descriptors, cv::NORM_L1), 0.0);
  EXPECT_EQ(back[0].hash, kf.hash);
  EXPECT_EQ(back[0].altitude_m, kf.altitude_m);
  EXPECT_EQ(store.sessions()[0].camera.fx, 300.0);
  EXPECT_EQ(store.sessions()[0].state, StoredSessionState::kRecording);
}

// Start-up: the keyframes' frame data come from a covering index (about 60 bytes a
// keyframe) instead of each 74 kB row's first page; a store written before the index gets it when
// opened, with its contents unchanged.
TEST(Store, FrameDataAreReadFromACoveringIndexThatOlderStoresGetWhenOpened) {
  ScopedTempDir dir("uwms_store");
  const std::string path = (dir.path() / "maps.db").string();
  std::mt19937 rng(4);
  std::int64_t s = 0;
  auto plan = [&](SessionStore& store, const char* columns = "") {
    sqlite3_stmt* st = nullptr;
    const std::string sql = std::string(
                                "EXPLAIN QUERY PLAN SELECT keyframe, frame_index, stamp, altitude, image_width, "
                                "image_height, num_features") +
                            columns + " FROM keyframes WHERE session = 1 ORDER BY keyframe";
    EXPECT_EQ(sqlite3_prepare_v2(store.handle(), sql.c_str(), -1, &st, nullptr), SQLITE_OK);
    std::string detail;
    while (sqlite3_step(st) == SQLITE_ROW) detail += reinterpret_cast<const char*>(sqlite3_column_text(st, 3));
    sqlite3_finalize(st);
    return detail;
  };
  {
    SessionStore store(path);
    s = store.addSession("s", camera320(), 10.0);
    for (int k = 0; k < 3; ++k) store.addKeyframe(randomKeyframe(s, k, 50, &rng), nullptr, nullptr);
    EXPECT_NE(plan(store).find("COVERING INDEX keyframes_frame"), std::string::npos) << plan(store);
    EXPECT_NE(plan(store, ", hash").find("COVERING INDEX keyframes_hash"), std::string::npos) << plan(store, ", hash");
    // As a store written before the indexes were.
    ASSERT_EQ(sqlite3_exec(store.handle(), "DROP INDEX keyframes_frame; DROP INDEX keyframes_hash", nullptr, nullptr,
                           nullptr),
              SQLITE_OK);
    EXPECT_EQ(plan(store).find("keyframes_frame"), std::string::npos);
    EXPECT_EQ(plan(store, ", hash").find("keyframes_hash"), std::string::npos);
  }
  SessionStore store(path);
  EXPECT_NE(plan(store).find("COVERING INDEX keyframes_frame"), std::string::npos) << plan(store);
  EXPECT_NE(plan(store, ", hash").find("COVERING INDEX keyframes_hash"), std::string::npos) << plan(store, ", hash");
  const std::vector<StoredKeyframe> back = store.keyframes(s, false);
  ASSERT_EQ(back.size(), 3u);
  for (int k = 0; k < 3; ++k) {
    EXPECT_EQ(back[k].keyframe, k);
    EXPECT_EQ(back[k].frame_index, 3 * k + 1);
    EXPECT_EQ(back[k].stamp_s, 0.25 * k);
    EXPECT_EQ(back[k].altitude_m, 2.0 + 0.01 * k);
    EXPECT_EQ(back[k].image_size, cv::Size(320, 240));
  }
}

TEST(Store, TheHistoryTableComesWithOpeningForWritingAndKeepsItsEntries) {
  ScopedTempDir dir("uwms_store");
  const std::string path = (dir.path() / "maps.db").string();
  const HistoryEntry e{1, "2026-11-25T02:13:04Z", "join", "automatic", "0+1", "0:1>1:1 0:2>1:2", "map 1 joined"};
  {
    SessionStore store(path);
    store.addSession("s", camera320(), 10.0);
    store.addHistory(e);
    EXPECT_THROW(store.addHistory(e), StoreError);  // the same id twice
    // As a store written before the table was.
    ASSERT_EQ(sqlite3_exec(store.handle(), "DROP TABLE history", nullptr, nullptr, nullptr), SQLITE_OK);
  }
  {
    const SessionStore read_only(path, StoreAccess::kReadOnly);
    EXPECT_TRUE(read_only.history().empty());  // no table: no history, nothing created
  }
  SessionStore store(path);  // opened for writing: the table again, empty
  EXPECT_TRUE(store.history().empty());
  store.addHistory(e);
  HistoryEntry second = e;
  second.id = 2;
  second.kind = "split";
  second.loops = "";
  store.addHistory(second);
  const std::vector<HistoryEntry> back = store.history();
  ASSERT_EQ(back.size(), 2u);
  for (const auto& [got, want] : {std::pair{back[0], e}, std::pair{back[1], second}}) {
    EXPECT_EQ(got.id, want.id);
    EXPECT_EQ(got.time_utc + got.kind + got.cause + got.sessions + "|" + got.loops + "|" + got.message,
              want.time_utc + want.kind + want.cause + want.sessions + "|" + want.loops + "|" + want.message);
  }
}

TEST(Store, TheDatumIsAMetaRowThatSurvivesReopeningAndIsReplaced) {
  ScopedTempDir dir("uwms_store");
  const std::string path = (dir.path() / "maps.db").string();
  const HashSettings hash{HashMode::kSortedDct, 7, 500, "x"};
  {
    SessionStore store(path);
    store.checkHashSettings(hash);
    EXPECT_FALSE(store.datum());
    store.setDatum("43.1,5.9,90,0");
    store.setDatum("43.2,5.8,30,1.5");  // replaced, not a second row
  }
  const SessionStore read_only(path, StoreAccess::kReadOnly);
  ASSERT_TRUE(read_only.datum());
  EXPECT_EQ(*read_only.datum(), "43.2,5.8,30,1.5");
  HashSettings back;
  ASSERT_TRUE(read_only.hashSettings(&back));  // the meta table's other rows read as before
  EXPECT_EQ(back.seed, 7u);
}

TEST(Store, EachMotionKeepsItsSource) {
  ScopedTempDir dir("uwms_store");
  const std::string path = (dir.path() / "maps.db").string();
  std::mt19937 rng(3);
  const std::vector<MotionSource> sources = {MotionSource::kVisual, MotionSource::kNav, MotionSource::kFused,
                                             MotionSource::kFallback, MotionSource::kNav};
  std::int64_t session = 0;
  {
    SessionStore store(path);
    session = store.addSession("s", camera320(), 10.0);
    store.addKeyframe(randomKeyframe(session, 0, 10, &rng), nullptr, nullptr);
    for (std::size_t k = 0; k < sources.size(); ++k) {
      StoredKeyframe kf = randomKeyframe(session, static_cast<int>(k) + 1, 10, &rng);
      kf.motion_source = sources[k];
      const UncertainPose2 m(Pose2(0.1 * k, 0, 0), diag(0.01, 0.01));
      store.addKeyframe(kf, &m, nullptr);
    }
  }
  SessionStore store(path);
  EXPECT_EQ(store.motionSources(session), sources);
  EXPECT_EQ(store.odometry(session).size(), sources.size());
}

TEST(Store, RefusesOtherHashSettings) {
  ScopedTempDir dir("uwms_store");
  const std::string path = (dir.path() / "maps.db").string();
  SessionStore store(path);
  HashSettings h{HashMode::kSortedDct, 7, 500, "x"};
  store.checkHashSettings(h);
  store.checkHashSettings(h);  // the same again: fine
  h.seed = 8;
  try {
    store.checkHashSettings(h);
    FAIL() << "other seed accepted";
  } catch (const StoreError& e) {
    EXPECT_NE(std::string(e.what()).find("projection_seed 7"), std::string::npos) << e.what();
  }
}

// Expects opening `path` to throw a StoreError mentioning the path and `words`, with the file
// left byte-identical.
void expectRefusedUnchanged(const std::string& path, const std::string& words) {
  const std::string before = readBytes(path);
  try {
    SessionStore store(path);
    FAIL() << path << " was opened";
  } catch (const StoreError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find(path), std::string::npos) << msg;
    EXPECT_NE(msg.find(words), std::string::npos) << msg;
  }
  EXPECT_EQ(readBytes(path), before) << "a failed open modified " << path;
}

TEST(Store, RefusesADamagedMetaRowAtTheOpen) {
  ScopedTempDir dir("uwms_store");
  const std::string path = (dir.path() / "maps.db").string();
  SessionStore(path).checkHashSettings({HashMode::kSortedDct, 7, 500, "x"});
  ASSERT_TRUE(testing_util::execSql(path, "UPDATE meta SET value = 'seven' WHERE key = 'projection_seed'"));
  expectRefusedUnchanged(path, "meta table is damaged");
  EXPECT_THROW(SessionStore(path, StoreAccess::kReadOnly), StoreError);
}

// A camera row nothing could have run with (a negative focal length, a principal point outside
// the image) is refused by name: merge_stores copied it and the export drew mosaics with it. An
// all-zero row is an unknown camera (older stores, keyframe 0 lost) and reads as one.
TEST(Store, RefusesADamagedCameraRowAndReadsAnUnknownOne) {
  ScopedTempDir dir("uwms_store");
  const std::string path = (dir.path() / "maps.db").string();
  const CameraIntrinsics cam = camera320();
  {
    SessionStore store(path);
    store.addSession("good", cam, 1.0);
    store.addSession("unknown", CameraIntrinsics(), 2.0);
  }
  {  // nor written
    SessionStore store(path);
    CameraIntrinsics bad = cam;
    bad.fx = -5;
    EXPECT_THROW(store.addSession("bad", bad, 3.0), StoreError);
  }
  const std::vector<StoredSession> read = SessionStore(path, StoreAccess::kReadOnly).sessions();
  ASSERT_EQ(read.size(), 2u);
  EXPECT_EQ(read[0].camera, cam);
  EXPECT_EQ(read[1].camera.width, 0);
  for (const char* damage : {"cam_fx = -5", "cam_cx = 400", "cam_width = 0"}) {
    const std::string copy = (dir.path() / "copy.db").string();
    std::filesystem::copy_file(path, copy, std::filesystem::copy_options::overwrite_existing);
    ASSERT_TRUE(testing_util::execSql(copy, std::string("UPDATE sessions SET ") + damage + " WHERE name = 'good'"));
    try {
      SessionStore(copy, StoreAccess::kReadOnly).sessions();
      ADD_FAILURE() << damage << ": read";
    } catch (const StoreError& e) {
      EXPECT_NE(std::string(e.what()).find("session 0 'good' has a damaged camera row"), std::string::npos)
          << damage << ": " << e.what();
    }
  }
}

TEST(Store, RefusesAFileThatIsNotADatabase) {
  ScopedTempDir dir("uwms_store");
  const std::string path = (dir.path() / "notes.txt").string();
  writeBytes(path, "session,index\n0,1\nthis is not a database at all, but longer than a header\n");
  expectRefusedUnchanged(path, "not an SQLite database");
}

std::string makeStore(const ScopedTempDir& dir) {
  const std::string path = (dir.path() / "maps.db").string();
  SessionStore store(path);
  BackendOptions opt = missionOptions();
  MultiSessionBackend backend(opt);
  Recorder r(&store, &backend);
  recordMission(&r);
  store.checkpoint();
  return path;
}

// SQLite keeps whatever a row holds whatever the column's type: a text 'NaN' in a REAL column was
// read as 0.0 without a word (the merge then re-optimised the map with it). Read as damaged, named.
TEST(Store, TextForNumbersPartBlobsAndATwiceNamedSessionAreDamagedAndNamed) {
  ScopedTempDir dir("uwms_store");
  const std::string clean = makeStore(dir);
  const std::string copy = (dir.path() / "copy.db").string();
  for (const auto& [sql, words] : std::vector<std::pair<std::string, std::string>>{
           {"UPDATE motions SET x = 'NaN' WHERE keyframe = 3", "column 'x' of table 'motions' holds the text 'NaN'"},
           {"UPDATE loops SET yaw = 'oops' WHERE id = (SELECT min(id) FROM loops)",
            "column 'yaw' of table 'loops' holds the text 'oops'"},
           {"UPDATE keyframes SET altitude = x'00' WHERE keyframe = 2",
            "column 'altitude' of table 'keyframes' holds a blob"},
           {"UPDATE keyframes SET frame_index = 2.5 WHERE keyframe = 2", "column 'frame_index' of table 'keyframes'"},
           // A blob that is not a whole number of its values was cut to the whole ones (a link's
           // loop list one byte short summarised one loop fewer); a session twice in one chain
           // silently became two maps.
           {"UPDATE links SET loops = substr(loops, 1, length(loops) - 1)",
            "column 'loops' of table 'links' holds a blob of"},
           {"UPDATE maps SET motions = substr(motions, 1, length(motions) - 3)",
            "column 'motions' of table 'maps' holds a blob of"},
           // Text where a blob belongs, 72 characters: they had been read as a covariance of nine tiny
           // doubles (positive semi-definite) and the link accepted.
           {"UPDATE links SET cov = substr(hex(zeroblob(36)), 1, 72)",
            "column 'cov' of table 'links' holds text where a blob belongs"},
           {"INSERT INTO map_sessions(map, position, session) SELECT map, 99, session FROM map_sessions "
            "WHERE position = 0 LIMIT 1; INSERT INTO links(map, position, x, y, yaw, cov, loops) SELECT map, 99, x, y, "
            "yaw, cov, loops FROM links LIMIT 1",
            "names session"},
           // Values no build writes, named with the row: each was kept or dropped without a word.
           {"UPDATE keyframes SET stamp = -9e999 WHERE keyframe = 2", "keyframe 2 of session"},
           // Outside the schema's CHECKs (written with them off): read as one of the allowed values.
           {"PRAGMA ignore_check_constraints = ON; UPDATE sessions SET state = 'done'",
            "column 'state' of table 'sessions' holds 'done' (damaged"},
           {"PRAGMA ignore_check_constraints = ON; UPDATE loops SET kind = 'Global'",
            "column 'kind' of table 'loops' holds 'Global' (damaged"},
           {"PRAGMA ignore_check_constraints = ON; UPDATE sessions SET state = CAST('finished' AS BLOB)",
            "column 'state' of table 'sessions' holds a non-text 'finished' (damaged"},
           // Text for a session id (read as session 0) and a keyframe past 32 bits (read as its low bits).
           {"UPDATE loops SET session_b = 'one' WHERE id = (SELECT min(id) FROM loops)",
            "column 'session_b' of table 'loops' holds the text 'one'"},
           {"UPDATE loops SET keyframe_a = keyframe_a + 4294967296 WHERE id = (SELECT min(id) FROM loops)",
            "beyond any count or index"},
           {"UPDATE map_sessions SET session = 'x' WHERE position = 0", "column 'session' of table 'map_sessions'"},
           {"UPDATE loops SET session_a = 77 WHERE id = (SELECT min(id) FROM loops)",
            "names a session the store does not hold"},
           {"UPDATE loops SET session_b = session_a, keyframe_b = keyframe_a WHERE id = (SELECT min(id) FROM loops)",
            "from a keyframe to itself"},
           {"UPDATE loops SET x = 9e999 WHERE id = (SELECT min(id) FROM loops)", "mean not finite"},
           // Finite but absurd: it had been written to the maps' outputs and copied by merge_stores.
           {"UPDATE loops SET y = -1e300 WHERE id = (SELECT min(id) FROM loops)", "mean farther than 1e7 m"},
           {"UPDATE motions SET y = 9e999 WHERE keyframe = 3", "motion 3: mean not finite"},
       }) {
    std::filesystem::copy_file(clean, copy, std::filesystem::copy_options::overwrite_existing);
    ASSERT_TRUE(testing_util::execSql(copy, sql));
    SessionStore store(copy, StoreAccess::kReadOnly);
    MultiSessionBackend restored(missionOptions());
    try {
      restoreStore(store, &restored, nullptr, nullptr);
      ADD_FAILURE() << sql << ": restored";
    } catch (const StoreError& e) {
      EXPECT_NE(std::string(e.what()).find(words), std::string::npos) << sql << ": " << e.what();
      EXPECT_NE(std::string(e.what()).find("session store " + copy + ": "), std::string::npos) << e.what();
    }
  }
}

TEST(Store, RefusesACorruptFile) {
  ScopedTempDir dir("uwms_store");
  const std::string path = makeStore(dir);
  std::string bytes = readBytes(path);
  ASSERT_GT(bytes.size(), 3 * 4096u);
  std::mt19937 rng(1);
  for (std::size_t i = 4096; i < bytes.size(); ++i) bytes[i] = static_cast<char>(rng());  // pages 2.. garbage
  writeBytes(path, bytes);
  expectRefusedUnchanged(path, "corrupt");
}

TEST(Store, CorruptKeyframePagesDoNotStopTheOpenAndFailWhereTheyAreRead) {
  // The open checks every table but the keyframes (whose pages are most of a store);
  // a keyframe's pages are checked when read. Every overflow page of the keyframes' rows garbage:
  // the store opens, frame data and hashes come from their indexes intact, each keyframe's
  // features fail to read with a StoreError.
  ScopedTempDir dir("uwms_store");
  const std::string path = (dir.path() / "maps.db").string();
  std::mt19937 rng(6);
  std::int64_t s = 0;
  std::vector<StoredKeyframe> written;
  std::vector<int> pages;
  int page_size = 0;
  {
    SessionStore store(path);
    s = store.addSession("s", camera320(), 10.0);
    for (int k = 0; k < 3; ++k) {
      written.push_back(randomKeyframe(s, k, 500, &rng));
      store.addKeyframe(written.back(), nullptr, nullptr);
    }
    store.checkpoint();
    sqlite3_stmt* st = nullptr;
    ASSERT_EQ(sqlite3_prepare_v2(store.handle(),
                                 "SELECT pageno, pgsize FROM dbstat WHERE name = 'keyframes' AND pagetype = 'overflow'",
                                 -1, &st, nullptr),
              SQLITE_OK);
    while (sqlite3_step(st) == SQLITE_ROW) {
      pages.push_back(sqlite3_column_int(st, 0));
      page_size = sqlite3_column_int(st, 1);
    }
    sqlite3_finalize(st);
  }
  ASSERT_GT(pages.size(), 30u);  // 3 keyframes of about 68 kB
  std::string bytes = readBytes(path);
  for (int p : pages)
    for (int i = 0; i < page_size; ++i)
      bytes[static_cast<std::size_t>(p - 1) * page_size + i] = static_cast<char>(rng());
  writeBytes(path, bytes);

  SessionStore store(path);  // opened: the keyframes' pages are not read at the open
  const std::vector<StoredKeyframe> frames = store.keyframes(s, SessionStore::KeyframeColumns::kHash);
  ASSERT_EQ(frames.size(), 3u);
  for (int k = 0; k < 3; ++k) {
    EXPECT_EQ(frames[k].frame_index, written[k].frame_index);
    EXPECT_EQ((frames[k].hash - written[k].hash).cwiseAbs().maxCoeff(), 0.0f) << k;
    EXPECT_THROW(store.keyframeFeatures(s, k), StoreError) << k;
  }
}

TEST(Store, RefusesAnotherSchemaVersionAndAnotherApplication) {
  ScopedTempDir dir("uwms_store");
  const std::string path = makeStore(dir);
  ASSERT_TRUE(testing_util::execSql(path, "PRAGMA user_version=99"));
  expectRefusedUnchanged(path, "schema version 99, this build reads version 2");

  const std::string other = (dir.path() / "other.db").string();
  ASSERT_TRUE(testing_util::execSql(other, "CREATE TABLE t(x); INSERT INTO t VALUES (1)"));
  expectRefusedUnchanged(other, "not a uw_multislam session store");
}

TEST(Store, RefusesAReadOnlyOrMissingPath) {
  ScopedTempDir dir("uwms_store");
  std::string path;
  if (::geteuid() == 0) {
    // root writes anywhere it has mode bits for; sysfs refuses new files even to root.
    path = "/sys/uwms_store_test.db";
  } else {
    const auto ro = dir.path() / "ro";
    std::filesystem::create_directories(ro);
    ::chmod(ro.c_str(), 0555);
    path = (ro / "maps.db").string();
  }
  try {
    SessionStore store(path);
    FAIL() << path << " was created";
  } catch (const StoreError& e) {
    EXPECT_NE(std::string(e.what()).find(path + ": cannot create"), std::string::npos) << e.what();
  }
  const std::string missing = (dir.path() / "no" / "such" / "maps.db").string();
  try {
    SessionStore store(missing);
    FAIL() << missing << " was created";
  } catch (const StoreError& e) {
    EXPECT_NE(std::string(e.what()).find("does not exist"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(std::filesystem::exists(dir.path() / "no"));
  // A store nobody may write (chmod 444) is refused, even as root, and left as it is.
  const std::string locked = (dir.path() / "locked.db").string();
  { SessionStore made(locked); }
  ::chmod(locked.c_str(), 0444);
  const auto before = std::filesystem::last_write_time(locked);
  const auto size = std::filesystem::file_size(locked);
  try {
    SessionStore store(locked);
    FAIL() << locked << " was opened for writing";
  } catch (const StoreError& e) {
    EXPECT_NE(std::string(e.what()).find("the file is read-only"), std::string::npos) << e.what();
  }
  EXPECT_EQ(std::filesystem::last_write_time(locked), before);
  EXPECT_EQ(std::filesystem::file_size(locked), size);
  EXPECT_NO_THROW(SessionStore(locked, StoreAccess::kReadOnly));  // reading it stays possible
}

TEST(Store, AFullDiskIsReportedAndLosesOnlyThatKeyframe) {
  ScopedTempDir dir("uwms_store");
  const std::string path = (dir.path() / "maps.db").string();
  SessionStore store(path);
  const std::int64_t s = store.addSession("s", camera320(), 0.0);
  std::mt19937 rng(3);
  // Simulate a full disk: the file may not grow past its current size plus a little.
  sqlite3_stmt* st = nullptr;
  ASSERT_EQ(sqlite3_prepare_v2(store.handle(), "PRAGMA page_count", -1, &st, nullptr), SQLITE_OK);
  ASSERT_EQ(sqlite3_step(st), SQLITE_ROW);
  const int pages = sqlite3_column_int(st, 0);
  sqlite3_finalize(st);
  const std::string limit = "PRAGMA max_page_count=" + std::to_string(pages + 40);
  ASSERT_EQ(sqlite3_exec(store.handle(), limit.c_str(), nullptr, nullptr, nullptr), SQLITE_OK);
  int written = 0;
  try {
    for (int k = 0; k < 100; ++k) {
      const UncertainPose2 m(Pose2(0.5, 0, 0), diag(0.02, 0.01));
      store.addKeyframe(randomKeyframe(s, k, 500, &rng), k > 0 ? &m : nullptr, nullptr);
      ++written;
    }
    FAIL() << "no full disk";
  } catch (const StoreError& e) {
    EXPECT_NE(std::string(e.what()).find("the disk is full"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
  }
  EXPECT_GT(written, 0);
  EXPECT_EQ(static_cast<int>(store.keyframes(s, false).size()), written);
  EXPECT_EQ(static_cast<int>(store.odometry(s).size()), written - 1);
  // With room again (the cap lifted: space freed) the same store object writes on.
  store.setMaxBytes(0);
  const UncertainPose2 m(Pose2(0.5, 0, 0), diag(0.02, 0.01));
  EXPECT_NO_THROW(store.addKeyframe(randomKeyframe(s, written, 500, &rng), &m, nullptr));
  EXPECT_EQ(static_cast<int>(store.keyframes(s, false).size()), written + 1);
}

// A child process writes keyframes and reports each commit through a pipe; it is killed with
// SIGKILL mid-run. Every reported keyframe must be in the store, with its motion.
TEST(Store, KillNineLosesAtMostTheKeyframeInFlight) {
  ScopedTempDir dir("uwms_store");
  const std::string path = (dir.path() / "maps.db").string();
  int fds[2];
  ASSERT_EQ(::pipe(fds), 0);
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    ::close(fds[0]);
    try {
      SessionStore store(path);
      const std::int64_t s = store.addSession("crash", camera320(), 0.0);
      std::mt19937 rng(4);
      for (int k = 0;; ++k) {
        const UncertainPose2 m(Pose2(0.5, 0, 0.01), diag(0.02, 0.01));
        store.addKeyframe(randomKeyframe(s, k, 500, &rng), k > 0 ? &m : nullptr, nullptr);
        const int committed = k + 1;
        if (::write(fds[1], &committed, sizeof committed) != sizeof committed) ::_exit(3);
      }
    } catch (...) {
      ::_exit(2);
    }
  }
  ::close(fds[1]);
  int committed = 0, n = 0;
  while (committed < 25 && ::read(fds[0], &n, sizeof n) == sizeof n) committed = n;
  ::kill(child, SIGKILL);
  int status = 0;
  ::waitpid(child, &status, 0);
  while (::read(fds[0], &n, sizeof n) == sizeof n) committed = n;  // reported before the kill
  ::close(fds[0]);
  ASSERT_TRUE(WIFSIGNALED(status)) << "the writer ended by itself (status " << status << ")";
  ASSERT_GE(committed, 25);

  SessionStore store(path);
  const auto sessions = store.sessions();
  ASSERT_EQ(sessions.size(), 1u);
  EXPECT_GE(sessions[0].keyframes, committed);
  EXPECT_LE(sessions[0].keyframes, committed + 1);  // the one in flight may have committed
  EXPECT_EQ(static_cast<int>(store.odometry(sessions[0].id).size()), sessions[0].keyframes - 1);
  MultiSessionBackend backend{BackendOptions()};
  const RestoredStore rs = restoreStore(store, &backend, nullptr, nullptr);
  EXPECT_EQ(backend.session(0).keyframes, sessions[0].keyframes);
  // Nothing to optimise (no loop): the restored trajectory is the stored motions composed, exactly.
  const std::vector<Pose2> poses = backend.sessionPoses(0);
  ASSERT_EQ(static_cast<int>(poses.size()), sessions[0].keyframes);
  Pose2 composed;
  for (int k = 0; k < sessions[0].keyframes; ++k) {
    if (k > 0) composed = compose(composed, Pose2(0.5, 0, 0.01));
    EXPECT_TRUE(approxEqual(poses[k], composed, 1e-12, 1e-12)) << k << ": " << poses[k] << " vs " << composed;
  }
  EXPECT_EQ(rs.keyframes, sessions[0].keyframes);
}

TEST(Store, FilesAreTheOwnersOnlyAndASymbolicLinkIsRefused) {
  ScopedTempDir dir("uwms_store");
  const std::string path = (dir.path() / "maps.db").string();
  auto mode = [](const std::string& p) {
    struct stat st {};
    return ::stat(p.c_str(), &st) == 0 ? static_cast<int>(st.st_mode & 0777) : -1;
  };
  {
    SessionStore store(path);
    store.addSession("mine", camera320(), 0.0);
    EXPECT_EQ(mode(path), 0600);
    EXPECT_EQ(mode(path + "-wal"), 0600);
    EXPECT_FALSE(std::filesystem::exists(path + ".lock"));  // the lock is on the file itself: no file beside it
  }
  const std::string link = (dir.path() / "link.db").string();
  ASSERT_EQ(::symlink(path.c_str(), link.c_str()), 0);
  const std::uintmax_t size = std::filesystem::file_size(path);
  try {
    SessionStore store(link);
    FAIL() << "a store opened through a symbolic link";
  } catch (const StoreError& e) {
    EXPECT_NE(std::string(e.what()).find("symbolic link"), std::string::npos) << e.what();
  }
  EXPECT_EQ(std::filesystem::file_size(path), size);
  EXPECT_FALSE(std::filesystem::exists(link + ".lock"));
  // A link to nowhere: refused too, and nothing is created where it points.
  const std::string dangling = (dir.path() / "dangling.db").string();
  ASSERT_EQ(::symlink((dir.path() / "elsewhere.db").c_str(), dangling.c_str()), 0);
  EXPECT_THROW(SessionStore{dangling}, StoreError);
  EXPECT_FALSE(std::filesystem::exists(dir.path() / "elsewhere.db"));
}

TEST(Store, ASecondWriterIsRefusedWithTheHolderNamedAndADeadHolderReleasesIt) {
  ScopedTempDir dir("uwms_store");
  const std::string path = (dir.path() / "maps.db").string();
  auto refusal = [&] {
    try {
      SessionStore second(path);
    } catch (const StoreError& e) {
      return std::string(e.what());
    }
    return std::string("(opened)");
  };
  {
    SessionStore first(path);
    first.addSession("mine", camera320(), 0.0);
    const std::string why = refusal();  // the same process, a second object: refused too
    EXPECT_NE(why.find("in use by pid " + std::to_string(::getpid())), std::string::npos) << why;
    EXPECT_EQ(first.sessions().size(), 1u);  // the holder goes on
  }
  // Another process holds it: refused, naming that process; once it is killed, the store opens.
  int ready[2], hold[2];
  ASSERT_EQ(::pipe(ready), 0);
  ASSERT_EQ(::pipe(hold), 0);
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    try {
      SessionStore store(path);
      const char c = 1;
      if (::write(ready[1], &c, 1) != 1) ::_exit(3);
      char wait = 0;
      if (::read(hold[0], &wait, 1) < 0) ::_exit(4);  // until the parent kills it
    } catch (...) {
      ::_exit(2);
    }
    ::_exit(0);
  }
  char c = 0;
  ASSERT_EQ(::read(ready[0], &c, 1), 1);
  const std::string why = refusal();
  EXPECT_NE(why.find("in use by pid " + std::to_string(child)), std::string::npos) << why;
  EXPECT_NE(why.find("one process writes a store at a time"), std::string::npos) << why;
  ::kill(child, SIGKILL);
  int status = 0;
  ::waitpid(child, &status, 0);
  SessionStore after(path);  // the kernel released the dead holder's lock
  EXPECT_EQ(after.sessions().size(), 1u);
}

// The open descriptors of the file `path` names held by this process (/proc/self/fd).
int descriptorsOf(const std::string& path) {
  struct stat target {};
  if (::stat(path.c_str(), &target) != 0) return -1;
  int n = 0;
  for (const auto& e : std::filesystem::directory_iterator("/proc/self/fd")) {
    struct stat st {};
    if (::stat(e.path().c_str(), &st) == 0 && st.st_dev == target.st_dev && st.st_ino == target.st_ino) ++n;
  }
  return n;
}

std::vector<std::string> namesIn(const std::filesystem::path& dir) {
  std::vector<std::string> out;
  for (const auto& e : std::filesystem::directory_iterator(dir)) out.push_back(e.path().filename().string());
  std::sort(out.begin(), out.end());
  return out;
}

// The lock is on the file, not on the name: a hard link, a rename (what a bind mount shows: the
// same file under another path) or a symbolic link to a held store is refused in this process like
// the same path, the holder named, and the refused open leaves nothing beside its path.
TEST(Store, AnotherPathToAHeldStoreIsRefusedInThisProcessAndLeavesNothing) {
  ScopedTempDir dir("uwms_store");
  const std::string path = (dir.path() / "c3.db").string();
  const std::string hard = (dir.path() / "c3hard.db").string();
  const std::string soft = (dir.path() / "c3soft.db").string();
  SessionStore first(path);
  const std::int64_t s = first.addSession("mine", camera320(), 0.0);
  ASSERT_EQ(::link(path.c_str(), hard.c_str()), 0);
  ASSERT_EQ(::symlink(path.c_str(), soft.c_str()), 0);
  const int held = descriptorsOf(path);
  auto refusal = [](const std::string& p) {
    try {
      SessionStore second(p);
    } catch (const StoreError& e) {
      return std::string(e.what());
    }
    return std::string("(opened)");
  };
  std::string why = refusal(hard);
  EXPECT_NE(why.find(hard + ": in use by pid " + std::to_string(::getpid()) + " "), std::string::npos) << why;
  EXPECT_NE(why.find("one process writes a store at a time"), std::string::npos) << why;
  why = refusal(soft);
  EXPECT_NE(why.find("symbolic link"), std::string::npos) << why;
  // No descriptor of the file was opened for the refusals (closing one would drop the POSIX locks
  // SQLite holds on it for the first store), and nothing appeared beside the other paths.
  EXPECT_EQ(descriptorsOf(path), held);
  EXPECT_EQ(namesIn(dir.path()),
            (std::vector<std::string>{"c3.db", "c3.db-shm", "c3.db-wal", "c3hard.db", "c3soft.db"}));
  // Moved under another name while held: still the held file.
  const std::string moved = (dir.path() / "moved.db").string();
  ASSERT_EQ(::rename(hard.c_str(), moved.c_str()), 0);
  why = refusal(moved);
  EXPECT_NE(why.find("in use by pid " + std::to_string(::getpid())), std::string::npos) << why;
  // The first store goes on, whole.
  std::mt19937 rng(4);
  first.addKeyframe(randomKeyframe(s, 0, 50, &rng), nullptr, nullptr);
  EXPECT_EQ(first.keyframes(s, false).size(), 1u);
  EXPECT_EQ(first.sessions().size(), 1u);
}

// A second process through a hard link: refused naming the first (its pid), and nothing appears
// beside the link (SQLite would have made a second WAL for the one file); the first store's data
// are whole once it ends.
TEST(Store, AHardLinkToAStoreHeldByAnotherProcessIsRefusedNamingIt) {
  ScopedTempDir dir("uwms_store");
  const std::string path = (dir.path() / "c3.db").string();
  const std::string hard = (dir.path() / "c3hard.db").string();
  { SessionStore made(path); }
  ASSERT_EQ(::link(path.c_str(), hard.c_str()), 0);
  int ready[2], hold[2];
  ASSERT_EQ(::pipe(ready), 0);
  ASSERT_EQ(::pipe(hold), 0);
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    int code = 0;
    try {
      SessionStore store(path);
      const std::int64_t s = store.addSession("first", camera320(), 0.0);
      std::mt19937 rng(9);
      for (int k = 0; k < 3; ++k) store.addKeyframe(randomKeyframe(s, k, 50, &rng), nullptr, nullptr);
      const char c = 1;
      if (::write(ready[1], &c, 1) != 1) ::_exit(3);
      char wait = 0;
      if (::read(hold[0], &wait, 1) < 0) code = 4;  // until the parent says so
      std::mt19937 rng2(10);
      store.addKeyframe(randomKeyframe(s, 3, 50, &rng2), nullptr, nullptr);  // after the refusal: still its
    } catch (...) {
      ::_exit(2);
    }
    ::_exit(code);
  }
  char c = 0;
  ASSERT_EQ(::read(ready[0], &c, 1), 1);
  std::string why = "(opened)";
  try {
    SessionStore second(hard);
  } catch (const StoreError& e) {
    why = e.what();
  }
  EXPECT_NE(why.find(hard + ": in use by pid " + std::to_string(child) + " "), std::string::npos) << why;
  EXPECT_NE(why.find("one process writes a store at a time"), std::string::npos) << why;
  EXPECT_FALSE(std::filesystem::exists(hard + "-wal"));
  EXPECT_FALSE(std::filesystem::exists(hard + "-shm"));
  EXPECT_FALSE(std::filesystem::exists(hard + ".lock"));
  ASSERT_EQ(::write(hold[1], &c, 1), 1);
  int status = 0;
  ASSERT_EQ(::waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFEXITED(status));
  ASSERT_EQ(WEXITSTATUS(status), 0);
  SessionStore after(hard);  // free now, through either path
  ASSERT_EQ(after.sessions().size(), 1u);
  EXPECT_EQ(after.keyframes(after.sessions()[0].id, false).size(), 4u);  // nothing of the holder's lost
}

// A reader beside a writer in this process (export beside a live back-end): its descriptor of the
// file is not closed while the writer lives (that would drop the writer's SQLite locks), and every
// descriptor is closed with the last store of the file.
TEST(Store, AReaderBesideAWriterInOneProcessKeepsItsDescriptorUntilTheWriterEnds) {
  ScopedTempDir dir("uwms_store");
  const std::string path = makeStore(dir);
  const int none = descriptorsOf(path);
  ASSERT_EQ(none, 0);
  {
    SessionStore writer(path);
    const int writing = descriptorsOf(path);
    {
      const SessionStore reader(path, StoreAccess::kReadOnly);
      EXPECT_EQ(reader.sessions().size(), writer.sessions().size());
      EXPECT_GT(descriptorsOf(path), writing);
    }
    EXPECT_GT(descriptorsOf(path), writing);  // the reader's own descriptor parked, not closed
    writer.addSession("after the reader", camera320(), 5.0);
  }
  EXPECT_EQ(descriptorsOf(path), 0);  // closed with the writer
  { const SessionStore reader(path, StoreAccess::kReadOnly); }
  EXPECT_EQ(descriptorsOf(path), 0);  // alone, a reader closes its own at once
  // A writer that ends while a reader of this process lives: its lock goes with it (its descriptor
  // is parked), so the next writer opens.
  {
    const SessionStore reader(path, StoreAccess::kReadOnly);
    { SessionStore writer(path); }
    SessionStore next(path);
    EXPECT_EQ(next.sessions().size(), reader.sessions().size());
  }
  EXPECT_EQ(descriptorsOf(path), 0);
}

// A refused open leaves nothing: a new store whose open fails removes the file it created; a
// link planted at its -wal or -shm is refused before SQLite could follow it; kCreateNew refuses
// anything already at the path.
TEST(Store, ARefusedOpenLeavesNothingBehind) {
  ScopedTempDir dir("uwms_store");
  ScopedTempDir outside("uwms_store_outside");
  const std::string victim = (outside.path() / "victim").string();
  writeBytes(victim, "precious");
  const std::string path = (dir.path() / "new.db").string();
  ASSERT_EQ(::symlink(victim.c_str(), (path + "-wal").c_str()), 0);
  try {
    SessionStore store(path);
    FAIL() << "opened beside a planted -wal link";
  } catch (const StoreError& e) {
    EXPECT_NE(std::string(e.what()).find("-wal file is a symbolic link"), std::string::npos) << e.what();
  }
  EXPECT_EQ(namesIn(dir.path()), std::vector<std::string>{"new.db-wal"});  // no 0-byte store left
  EXPECT_EQ(readBytes(victim), "precious");
  std::filesystem::remove(path + "-wal");
  // kCreateNew: an existing file (a store too) is refused and left as it is.
  const std::string existing = makeStore(dir);
  const std::string bytes = readBytes(existing);
  EXPECT_THROW(SessionStore(existing, StoreAccess::kCreateNew), StoreError);
  EXPECT_EQ(readBytes(existing), bytes);
  {
    SessionStore made(path, StoreAccess::kCreateNew);
    EXPECT_TRUE(made.sessions().empty());
  }
  // A store nobody may write is refused and nothing is created beside it.
  ::chmod(path.c_str(), 0400);
  EXPECT_THROW(SessionStore{path}, StoreError);
  EXPECT_FALSE(std::filesystem::exists(path + "-wal"));
  EXPECT_FALSE(std::filesystem::exists(path + "-shm"));
}

// A mission cut by a crash: the last session never ended and its map was saved before its last
// keyframes. The reload has every keyframe; the saved part of the map comes back exactly, the
// rest with its odometry, and the loops pending are optimised at the next flush.
TEST(Store, ASessionCutByACrashComesBackWithEveryKeyframe) {
  ScopedTempDir dir("uwms_store");
  const std::string path = (dir.path() / "maps.db").string();
  BackendOptions opt = missionOptions();
  opt.optimise_every = 1;
  MultiSessionBackend original(opt);
  std::vector<Pose2> saved_poses;
  {
    SessionStore store(path);
    Recorder r(&store, &original);
    recordMission(&r);
    const int d = r.start("d");  // along session 0, 0.1 m beside it
    for (int k = 1; k < 12; ++k) {
      std::vector<BackendLoop> loops;
      if (k >= 2 && k <= 6) {
        loops.push_back({0, k, d, k, UncertainPose2(Pose2(0.0, 0.1, 0.0), diag(0.01, 0.005))});
      }
      // 4.8 m where the odometry says 5.0 m: optimising must move the trajectory (checked below).
      if (k == 11) loops.push_back({d, 1, d, 11, UncertainPose2(Pose2(4.8, 0.0, 0.0), diag(0.01, 0.005))});
      r.step(d, Pose2(0.5, 0.0, 0.0), loops);
      if (k == 8) {  // the join happened at k = 6: the map is saved, then the crash comes later
        ASSERT_EQ(original.mapOf(d), 0);
        saveBackendMaps(&store, original, r.session_ids, r.loop_ids);
        saved_poses = original.sessionPoses(d);
      }
    }
  }  // no endSession, no saveMaps: as if killed
  SessionStore store(path);
  MultiSessionBackend restored(opt);
  restoreStore(store, &restored, nullptr, nullptr);
  ASSERT_EQ(restored.numSessions(), 4);
  EXPECT_FALSE(restored.session(3).recording);
  EXPECT_EQ(restored.session(3).keyframes, 12);
  EXPECT_EQ(restored.mapOf(3), 0);
  const std::vector<Pose2> poses = restored.sessionPoses(3);
  for (std::size_t k = 0; k < saved_poses.size(); ++k) EXPECT_NEAR(poses[k].x(), saved_poses[k].x(), 1e-12) << k;
  EXPECT_NEAR(between(poses[8], poses[11]).x(), 1.5, 1e-9);  // the odometry after the save
  EXPECT_NEAR(between(poses[1], poses[11]).x(), 5.0, 1e-9);  // the loop is not applied yet
  restored.flush();  // the intra-session loop, not yet optimised when the map was saved
  EXPECT_GT(restored.stats().optimisations, 0);
  // The correction, in closed form: session d hangs off the rest of the map by one link, its
  // motions are pure x (0.5 m, sigma_o = 0.02 m each) and the loop over the 10 motions from
  // keyframe 1 to 11 says 4.8 m (sigma_l = 0.01 m). The problem is linear in x: the sum of the
  // motions is the precision-weighted mean of 10 x 0.5 m (variance 10 sigma_o^2) and 4.8 m,
  // 4.8049 m; the loop's residual, 0.5 sigma_l, is well inside the robust loss's quadratic part.
  const double var_odo = 10 * 0.02 * 0.02, var_loop = 0.01 * 0.01;
  const double expected = (5.0 * var_loop + 4.8 * var_odo) / (var_loop + var_odo);
  const std::vector<Pose2> after = restored.sessionPoses(3);
  const Pose2 span = between(after[1], after[11]);
  EXPECT_NEAR(span.x(), expected, 1e-6);
  EXPECT_NEAR(span.y(), 0.0, 1e-6);
  EXPECT_NEAR(span.yaw(), 0.0, 1e-6);
  for (int k = 2; k <= 11; ++k)  // spread evenly over the motions
    EXPECT_NEAR(between(after[k - 1], after[k]).x(), expected / 10, 1e-6) << k;
}

// A position prior written when it is accepted (addPositionPrior), between two saves of the maps:
// on a saved map it joins that map's priors and makes it pending; on a session alone in its map
// since it started (no map stored) it stores that map, so that a restart has the prior's frame.
TEST(Store, APositionPriorWrittenBetweenSavesComesBackWithItsMap) {
  ScopedTempDir dir("uwms_store");
  const std::string path = (dir.path() / "maps.db").string();
  MultiSessionBackend original(missionOptions());
  const Eigen::Matrix2d cov = (Eigen::Matrix2d() << 0.04, 0.01, 0.01, 0.09).finished();
  std::int64_t a = 0, b = 0;
  {
    SessionStore store(path);
    Recorder r(&store, &original);
    const int s0 = r.start("a");
    for (int k = 1; k < 6; ++k) r.step(s0, Pose2(0.5, 0.0, 0.0));
    r.end(s0);  // its map saved
    const int s1 = r.start("b");
    for (int k = 1; k < 6; ++k) r.step(s1, Pose2(0.5, 0.0, 0.0));
    a = r.session_ids[s0];
    b = r.session_ids[s1];
    ASSERT_EQ(store.maps().size(), 1u);  // session b's map not yet
    store.addPositionPrior(a, {a, 3, Eigen::Vector2d(1.5, 0.2), cov, false});
    store.addPositionPrior(b, {b, 2, Eigen::Vector2d(1.0, -0.2), cov, false});
    store.addPositionPrior(b, {b, 4, Eigen::Vector2d(2.0, -0.2), cov, false});  // b's map stored once
  }  // no endSession, no saveMaps: as if killed
  SessionStore store(path);
  const std::vector<StoredMap> maps = store.maps();
  ASSERT_EQ(maps.size(), 2u);
  EXPECT_EQ(maps[0].chain, std::vector<std::int64_t>{a});
  EXPECT_EQ(maps[0].pending, 1);
  ASSERT_EQ(maps[0].priors.size(), 1u);
  EXPECT_EQ(maps[0].priors[0].position, Eigen::Vector2d(1.5, 0.2));
  EXPECT_EQ(maps[0].priors[0].covariance, cov);
  EXPECT_EQ(maps[1].chain, std::vector<std::int64_t>{b});
  EXPECT_TRUE(maps[1].motions.empty());  // its odometry's
  EXPECT_EQ(maps[1].pending, 2);
  ASSERT_EQ(maps[1].priors.size(), 2u);
  EXPECT_EQ(maps[1].priors[1].keyframe, 4);
  MultiSessionBackend restored(missionOptions());
  const RestoredStore out = restoreStore(store, &restored, nullptr, nullptr);
  EXPECT_TRUE(out.notes.empty());
  ASSERT_EQ(restored.priors().size(), 3u);
  EXPECT_EQ(restored.priors()[1].session, 1);
  EXPECT_EQ(restored.priors()[1].position, Eigen::Vector2d(1.0, -0.2));
  EXPECT_EQ(restored.dueMaps().size(), 0u);  // not deferred: flush optimises them
  restored.flush();
  EXPECT_LT(restored.sessionPoses(1)[2].y(), -1e-3);
  EXPECT_GT(restored.sessionPoses(0)[3].y(), 1e-3);
}

TEST(Store, APositionPriorOnAMapTheStoreDoesNotHaveIsRefusedNotOrphaned) {
  ScopedTempDir dir("uwms_store");
  const std::string path = (dir.path() / "maps.db").string();
  MultiSessionBackend original(missionOptions());
  SessionStore store(path);
  Recorder r(&store, &original);
  const int s0 = r.start("a");
  for (int k = 1; k < 4; ++k) r.step(s0, Pose2(0.5, 0.0, 0.0));
  const std::int64_t a = r.session_ids[s0];
  // Map a + 7 (a join whose save failed, say) is not stored and is not the prior's session's own.
  EXPECT_THROW(store.addPositionPrior(a + 7, {a, 2, Eigen::Vector2d(1.0, 0.0), Eigen::Matrix2d::Identity(), false}),
               StoreError);
  EXPECT_TRUE(store.maps().empty());
  sqlite3_stmt* st = nullptr;  // and no row of the refused write left behind (rolled back)
  ASSERT_EQ(sqlite3_prepare_v2(store.handle(), "SELECT count(*) FROM position_priors", -1, &st, nullptr), SQLITE_OK);
  ASSERT_EQ(sqlite3_step(st), SQLITE_ROW);
  EXPECT_EQ(sqlite3_column_int(st, 0), 0);
  sqlite3_finalize(st);
}

// Read-only (export_survey): a missing or empty file is refused and not created; a store reads the
// same as through a writer, every write is refused, and nothing appears beside the file (no lock,
// no -wal/-shm) nor changes in it.
TEST(Store, ReadOnlyReadsEverythingAndWritesNothing) {
  ScopedTempDir dir("uwms_store");
  const std::string missing = (dir.path() / "none.db").string();
  EXPECT_THROW(SessionStore(missing, StoreAccess::kReadOnly), StoreError);
  EXPECT_FALSE(std::filesystem::exists(missing));
  const std::string empty = (dir.path() / "empty.db").string();
  writeBytes(empty, "");
  EXPECT_THROW(SessionStore(empty, StoreAccess::kReadOnly), StoreError);
  EXPECT_EQ(readBytes(empty), "");

  ScopedTempDir dir2("uwms_store");
  const std::string path = makeStore(dir2);
  std::filesystem::remove(path + ".lock");
  {
    const SessionStore rw(path);
    const SessionStore ro(path, StoreAccess::kReadOnly);  // beside a writer: no lock taken
    ASSERT_EQ(ro.sessions().size(), rw.sessions().size());
    EXPECT_EQ(ro.loops().size(), rw.loops().size());
    EXPECT_EQ(ro.maps().size(), rw.maps().size());
    for (const StoredSession& s : rw.sessions()) {
      EXPECT_EQ(ro.odometry(s.id).size(), rw.odometry(s.id).size());
      const std::vector<StoredKeyframe> kfs = rw.keyframes(s.id, true);
      const std::vector<std::vector<std::uint8_t>> thumbs = ro.thumbnails(s.id);
      ASSERT_EQ(thumbs.size(), kfs.size());
      for (std::size_t k = 0; k < kfs.size(); ++k) EXPECT_EQ(thumbs[k], kfs[k].thumbnail) << k;
    }
  }
  std::filesystem::remove(path + ".lock");
  const std::string before = readBytes(path);
  {
    SessionStore ro(path, StoreAccess::kReadOnly);
    EXPECT_THROW(ro.addSession("x", camera320(), 0.0), StoreError);
    EXPECT_THROW(ro.saveMaps({}, {}, {}), StoreError);
  }
  EXPECT_EQ(readBytes(path), before);
  std::vector<std::string> names;
  for (const auto& e : std::filesystem::directory_iterator(dir2.path())) names.push_back(e.path().filename().string());
  EXPECT_EQ(names, std::vector<std::string>{"maps.db"});
}

// Every row a query gives, byte for byte (type and bytes of each column), for comparing a table
// before and after a change through another connection (read-only).
std::string rowBytes(const std::string& path, const std::string& sql) {
  sqlite3* db = nullptr;
  EXPECT_EQ(sqlite3_open_v2(path.c_str(), &db, SQLITE_OPEN_READONLY, nullptr), SQLITE_OK);
  sqlite3_stmt* st = nullptr;
  EXPECT_EQ(sqlite3_prepare_v2(db, sql.c_str(), -1, &st, nullptr), SQLITE_OK) << sql;
  std::string out;
  while (sqlite3_step(st) == SQLITE_ROW) {
    for (int c = 0; c < sqlite3_column_count(st); ++c) {
      const int type = sqlite3_column_type(st, c);
      out += std::to_string(type) + ":";
      if (type == SQLITE_FLOAT) {
        const double v = sqlite3_column_double(st, c);
        out.append(reinterpret_cast<const char*>(&v), sizeof v);
      } else if (type != SQLITE_NULL) {
        const void* p = sqlite3_column_blob(st, c);
        out.append(static_cast<const char*>(p), static_cast<std::size_t>(sqlite3_column_bytes(st, c)));
      }
      out += "|";
    }
    out += "\n";
  }
  sqlite3_finalize(st);
  sqlite3_close(db);
  return out;
}

std::string integrityOf(const std::string& path) {
  sqlite3* db = nullptr;
  sqlite3_open_v2(path.c_str(), &db, SQLITE_OPEN_READONLY, nullptr);
  sqlite3_stmt* st = nullptr;
  std::string v = "unreadable";
  if (sqlite3_prepare_v2(db, "PRAGMA integrity_check", -1, &st, nullptr) == SQLITE_OK && sqlite3_step(st) == SQLITE_ROW)
    v = reinterpret_cast<const char*>(sqlite3_column_text(st, 0));
  sqlite3_finalize(st);
  sqlite3_close(db);
  return v;
}

// What a session owns in the store, byte for byte: its session row, keyframes (every blob) and
// motions.
std::string sessionRows(const std::string& path, std::int64_t id) {
  const std::string s = std::to_string(id);
  return rowBytes(path, "SELECT * FROM sessions WHERE id = " + s) +
         rowBytes(path, "SELECT * FROM keyframes WHERE session = " + s + " ORDER BY keyframe") +
         rowBytes(path, "SELECT * FROM motions WHERE session = " + s + " ORDER BY keyframe");
}

// The loops that do not touch session `id`, byte for byte.
std::string loopsWithout(const std::string& path, std::int64_t id) {
  const std::string s = std::to_string(id);
  return rowBytes(path, "SELECT * FROM loops WHERE session_a != " + s + " AND session_b != " + s + " ORDER BY id");
}

// Deleting a session (an interrupted run discarded): one transaction that takes out
// its rows and its loops, cuts it out of the maps, and leaves every other session's rows byte for
// byte as they were; the store passes integrity_check and restores into a back-end.
TEST(Store, DeletingASessionLeavesTheOthersByteForByteAndCutsItOutOfTheMaps) {
  ScopedTempDir dir("uwms_store");
  const std::string path = (dir.path() / "maps.db").string();
  BackendOptions opt = missionOptions();
  opt.optimise_every = 1;
  MultiSessionBackend original(opt);
  std::vector<std::int64_t> ids;
  {
    SessionStore store(path);
    Recorder r(&store, &original);
    recordMission(&r);  // 1 joined to 0; 2 split off again
    ids = r.session_ids;
    ASSERT_TRUE(original.join(0, 2, 1).ok());  // now one map of three sessions
    saveBackendMaps(&store, original, r.session_ids, r.loop_ids);
  }
  const std::vector<int> chain = original.chain(0);
  ASSERT_EQ(chain.size(), 3u);
  const int middle = chain[1], end = chain[2];
  std::vector<std::string> before;
  for (std::int64_t id : ids) before.push_back(sessionRows(path, id));
  const std::string m = std::to_string(ids[static_cast<std::size_t>(middle)]);
  const std::string other_loops = loopsWithout(path, ids[static_cast<std::size_t>(middle)]);
  const std::string all_loops = rowBytes(path, "SELECT * FROM loops ORDER BY id");
  const std::string splits_kept = rowBytes(path, "SELECT * FROM split_pairs WHERE session_a != " + m +
                                                     " AND session_b != " + m + " ORDER BY session_a, session_b");

  // An unknown id among the ones to delete: refused, naming it, and nothing is deleted.
  {
    SessionStore store(path);
    try {
      store.deleteSessions({ids[static_cast<std::size_t>(middle)], 999});
      FAIL() << "an unknown session was deleted";
    } catch (const StoreError& e) {
      EXPECT_NE(std::string(e.what()).find("999"), std::string::npos) << e.what();
    }
  }
  for (std::size_t i = 0; i < ids.size(); ++i) EXPECT_EQ(sessionRows(path, ids[i]), before[i]) << i;
  EXPECT_EQ(rowBytes(path, "SELECT * FROM loops ORDER BY id"), all_loops);

  // The middle session of the chain: the map falls apart into the sessions before and after it.
  {
    SessionStore store(path);
    store.deleteSessions({ids[static_cast<std::size_t>(middle)]});
  }
  EXPECT_EQ(integrityOf(path), "ok");
  for (std::size_t i = 0; i < ids.size(); ++i) {
    if (static_cast<int>(i) == middle) {
      EXPECT_EQ(rowBytes(path, "SELECT * FROM keyframes WHERE session = " + std::to_string(ids[i])), "");
      EXPECT_EQ(rowBytes(path, "SELECT * FROM motions WHERE session = " + std::to_string(ids[i])), "");
      EXPECT_EQ(sessionRows(path, ids[i]), "");
    } else {
      EXPECT_EQ(sessionRows(path, ids[i]), before[i]) << "session " << i << " changed";
    }
  }
  EXPECT_EQ(rowBytes(path, "SELECT * FROM loops ORDER BY id"), other_loops);  // its own loops gone, the rest kept
  EXPECT_EQ(rowBytes(path, "SELECT count(*) FROM map_sessions WHERE session = " +
                               std::to_string(ids[static_cast<std::size_t>(middle)])),
            rowBytes(path, "SELECT 0"));
  {
    SessionStore store(path);
    EXPECT_EQ(store.sessions().size(), 2u);
    const std::vector<StoredMap> maps = store.maps();
    ASSERT_EQ(maps.size(), 2u);  // [chain[0]] and [chain[2]]
    for (const StoredMap& m : maps) {
      EXPECT_EQ(m.chain.size(), 1u);
      EXPECT_TRUE(m.links.empty());
      EXPECT_TRUE(m.motions.empty());  // optimised again from the odometry
      EXPECT_GE(m.pending, 1);
    }
    EXPECT_EQ(maps[0].chain.front(), ids[static_cast<std::size_t>(chain[0])]);
    EXPECT_EQ(maps[1].chain.front(), ids[static_cast<std::size_t>(end)]);
    for (const StoredLoop& l : store.loops()) {
      EXPECT_NE(l.session_a, ids[static_cast<std::size_t>(middle)]);
      EXPECT_NE(l.session_b, ids[static_cast<std::size_t>(middle)]);
    }
    MultiSessionBackend restored(opt);
    const RestoredStore rs = restoreStore(store, &restored, nullptr, nullptr);
    EXPECT_EQ(restored.numSessions(), 2);
    EXPECT_NE(restored.mapOf(0), restored.mapOf(1));
    EXPECT_EQ(rs.keyframes, 33 - original.session(middle).keyframes);
    restored.flush();
    // The restored sessions' odometry is the stored one, motion for motion.
    for (int s = 0; s < 2; ++s) {
      const std::vector<UncertainPose2> odo = store.odometry(rs.session_ids[static_cast<std::size_t>(s)]);
      EXPECT_EQ(restored.session(s).keyframes, static_cast<int>(odo.size()) + 1);
    }
  }
  EXPECT_EQ(rowBytes(path, "SELECT * FROM split_pairs ORDER BY session_a, session_b"), splits_kept);
  EXPECT_EQ(rowBytes(path, "SELECT count(*) FROM split_pairs WHERE session_a = " + m + " OR session_b = " + m),
            rowBytes(path, "SELECT 0"));
}

// The session at the end of a chain (what an interrupted run usually is: joined to a stored map
// by its global loops): the chain keeps the rest; a map it was not in stays byte for byte.
// A session's id is its store id for life: a deleted session's id is never given again, not
// even when it was the largest (SQLite would reuse it) and the store is opened again; an id given
// explicitly (the session manager's) must be new.
TEST(Store, ASessionIdIsGivenOnceAlsoWhenTheLargestWasDeletedAndTheStoreReopened) {
  ScopedTempDir dir("uwms_store");
  const std::string path = (dir.path() / "maps.db").string();
  {
    SessionStore store(path);
    EXPECT_EQ(store.nextSessionId(), 0);  // never held a session
    EXPECT_EQ(store.addSession("a", camera320(), 0.0, 0), 0);
    EXPECT_EQ(store.addSession("b", camera320(), 0.0, 1), 1);
    EXPECT_EQ(store.addSession("c", camera320(), 0.0, 2), 2);
    EXPECT_EQ(store.nextSessionId(), 3);
    EXPECT_THROW(store.addSession("taken", camera320(), 0.0, 1), StoreError);
    store.deleteSessions({2});
    EXPECT_EQ(store.nextSessionId(), 3);  // SQLite alone would give 2 again
  }
  SessionStore store(path);
  EXPECT_EQ(store.nextSessionId(), 3);
  try {
    store.addSession("again", camera320(), 0.0, 2);
    ADD_FAILURE() << "a deleted session's id was given again";
  } catch (const StoreError& e) {
    EXPECT_NE(std::string(e.what()).find("id 2 was a deleted session's"), std::string::npos) << e.what();
  }
  EXPECT_EQ(store.addSession("d", camera320(), 0.0), 3);  // no id given: past the deleted one too
  EXPECT_EQ(store.addSession("e", camera320(), 0.0, 7), 7);
  EXPECT_EQ(store.nextSessionId(), 8);
  std::vector<std::int64_t> ids;
  for (const StoredSession& st : store.sessions()) ids.push_back(st.id);
  EXPECT_EQ(ids, (std::vector<std::int64_t>{0, 1, 3, 7}));
}

TEST(Store, DeletingTheLastSessionOfAChainKeepsTheRestOfTheMap) {
  ScopedTempDir dir("uwms_store");
  const std::string path = (dir.path() / "maps.db").string();
  BackendOptions opt = missionOptions();
  opt.optimise_every = 1;
  MultiSessionBackend original(opt);
  std::vector<std::int64_t> ids;
  {
    SessionStore store(path);
    Recorder r(&store, &original);
    recordMission(&r);  // map 0: [0, 1]; map 2: [2]
    ids = r.session_ids;
  }
  ASSERT_EQ(original.chain(0), (std::vector<int>{0, 1}));
  const std::string map2 = "SELECT * FROM maps WHERE id = " + std::to_string(ids[2]);
  const std::string map2_before = rowBytes(path, map2);
  ASSERT_NE(map2_before, "");
  const std::string s0 = sessionRows(path, ids[0]), s2 = sessionRows(path, ids[2]);
  const std::string other_loops = loopsWithout(path, ids[1]);
  {
    SessionStore store(path);
    store.deleteSessions({ids[1]});
  }
  EXPECT_EQ(integrityOf(path), "ok");
  EXPECT_EQ(rowBytes(path, map2), map2_before);
  EXPECT_EQ(sessionRows(path, ids[0]), s0);
  EXPECT_EQ(sessionRows(path, ids[2]), s2);
  EXPECT_EQ(rowBytes(path, "SELECT * FROM loops ORDER BY id"), other_loops);
  SessionStore store(path);
  const std::vector<StoredMap> maps = store.maps();
  ASSERT_EQ(maps.size(), 2u);
  EXPECT_EQ(maps[0].chain, std::vector<std::int64_t>{ids[0]});
  EXPECT_TRUE(maps[0].links.empty());
  EXPECT_GE(maps[0].pending, 1);
  MultiSessionBackend restored(opt);
  restoreStore(store, &restored, nullptr, nullptr);
  ASSERT_EQ(restored.numSessions(), 2);
  EXPECT_EQ(restored.session(0).keyframes, 13);
  EXPECT_EQ(restored.session(1).keyframes, 8);
  EXPECT_NE(restored.mapOf(0), restored.mapOf(1));
}

// An interrupted run over a folder (frames 100..140): its recording piece and the finished piece
// of the same run before it are found; an earlier complete run of the folder, another folder's
// session and a session without keyframes are not part of it. finish ends it as stored, discard
// deletes exactly its sessions.
TEST(Store, AnInterruptedRunIsFoundWithItsPiecesAndFinishedOrDiscarded) {
  ScopedTempDir dir("uwms_store");
  const std::string path = (dir.path() / "maps.db").string();
  std::vector<FrameRecord> folder;
  for (int i = 100; i <= 140; ++i) folder.push_back({i, "", 10.0 + 0.1 * i, 2.0});
  std::mt19937 rng(7);
  std::map<std::string, std::int64_t> id;
  {
    SessionStore store(path);
    auto add = [&](const std::string& name, const std::vector<int>& frames, bool finished, double offset = 0.0) {
      id[name] = store.addSession(name, camera320(), 0.0);
      for (std::size_t k = 0; k < frames.size(); ++k) {
        StoredKeyframe kf = randomKeyframe(id[name], static_cast<int>(k), 10, &rng);
        if (frames[k] >= 0) {
          kf.frame_index = frames[k];
          kf.stamp_s = 10.0 + 0.1 * frames[k] + offset;
        }
        const UncertainPose2 m(Pose2(0.5, 0, 0), diag(0.02, 0.01));
        store.addKeyframe(kf, k > 0 ? &m : nullptr, nullptr);
      }
      if (finished) store.endSession(id[name], 99.0);
    };
    add("empty", {}, false);                  // a crash before its first keyframe: no id
    add("other folder", {-1, -1, -1}, true);  // frames 1, 4, 7: not the folder's
    add("complete", {100, 120, 140}, true);   // an earlier complete run of the folder
    add("shifted", {100, 104}, true, 1e-3);   // same indexes, other stamps: not the folder's
    add("f", {100, 102, 104}, true);          // the interrupted run's first piece
    add("f#1", {110, 112}, false);            // ... and its second, cut by the kill
  }
  {
    SessionStore store(path);
    const std::vector<InterruptedRun> runs = findInterruptedRuns(store, folder);
    ASSERT_EQ(runs.size(), 1u);
    EXPECT_EQ(runs[0].store_ids, (std::vector<std::int64_t>{id["f"], id["f#1"]}));
    // A session's id is its store id ("empty" has one too, though it is never restored).
    EXPECT_EQ(runs[0].ids, (std::vector<int>{static_cast<int>(id["f"]), static_cast<int>(id["f#1"])}));
    EXPECT_EQ(runs[0].ids, (std::vector<int>{4, 5}));
    EXPECT_EQ(runs[0].name, "f#1");
    EXPECT_EQ(runs[0].keyframes, 5);
    EXPECT_DOUBLE_EQ(runs[0].last_stamp_s, 10.0 + 0.1 * 112);
    std::vector<FrameRecord> other = folder;
    other.erase(other.begin() + 12);  // frame 112 missing: f#1 is not made of these frames
    ASSERT_EQ(findInterruptedRuns(store, other).size(), 0u);
  }
  const std::string copy = (dir.path() / "copy.db").string();
  std::filesystem::copy_file(path, copy);
  {
    SessionStore store(path);
    resolveInterruptedRun(&store, findInterruptedRuns(store, folder).at(0), InterruptedChoice::kFinish);
    EXPECT_TRUE(findInterruptedRuns(store, folder).empty());
    const StoredSession last = store.sessions().back();
    EXPECT_EQ(last.state, StoredSessionState::kFinished);
    EXPECT_DOUBLE_EQ(last.end_stamp_s, 10.0 + 0.1 * 112);
    EXPECT_EQ(store.sessions().size(), 6u);
  }
  {
    SessionStore store(copy);
    resolveInterruptedRun(&store, findInterruptedRuns(store, folder).at(0), InterruptedChoice::kDiscard);
    std::vector<std::string> names;
    for (const StoredSession& s : store.sessions()) names.push_back(s.name);
    EXPECT_EQ(names, (std::vector<std::string>{"empty", "other folder", "complete", "shifted"}));
  }
  EXPECT_EQ(integrityOf(copy), "ok");
}

// A full disk in the middle of saving the maps (the cap is SQLite's max_page_count):
// the new state is refused with "the disk is full" after its first rows were written, the
// transaction is rolled back, and the store keeps the previous maps byte for byte and restores
// exactly as before. With room again the same save succeeds.
TEST(Store, AFullDiskWhileSavingTheMapsKeepsThePreviousMapsAndTheSameRestore) {
  ScopedTempDir dir("uwms_store");
  const std::string path = (dir.path() / "maps.db").string();
  BackendOptions opt = missionOptions();
  opt.optimise_every = 1;
  MultiSessionBackend original(opt);
  {
    SessionStore store(path);
    Recorder r(&store, &original);
    recordMission(&r);
  }
  const std::vector<std::string> tables = {
      "SELECT * FROM maps ORDER BY id", "SELECT * FROM map_sessions ORDER BY map, position",
      "SELECT * FROM links ORDER BY map, position", "SELECT * FROM split_pairs", "SELECT * FROM loops ORDER BY id"};
  std::vector<std::string> before;
  for (const std::string& t : tables) before.push_back(rowBytes(path, t));
  MultiSessionBackend before_restore(opt);
  std::vector<StoredMap> bigger;
  std::vector<StoredLoop> states;
  {
    SessionStore store(path);
    restoreStore(store, &before_restore, nullptr, nullptr);
    // The next state: every map as it is, then one whose motions need about 2 MB more than the
    // file has (written last, so the save fails in its middle, after rows were written).
    bigger = store.maps();
    ASSERT_EQ(bigger.size(), 2u);
    StoredMap big = bigger[0];
    big.motions.resize(20000, big.motions.front());
    bigger[0] = bigger[1];
    bigger[1] = big;
    states = store.loops();
    for (StoredLoop& l : states) l.applied = !l.applied;  // every loop's state changes too
    store.checkpoint();
    store.setMaxBytes(std::filesystem::file_size(path));
    try {
      store.saveMaps(bigger, states, {});
      FAIL() << "the save fitted under the cap";
    } catch (const StoreError& e) {
      EXPECT_NE(std::string(e.what()).find("the disk is full"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
    }
    // The store is still usable: reads work, and the failed save left nothing half-written.
    EXPECT_EQ(store.maps().size(), 2u);
  }
  EXPECT_EQ(integrityOf(path), "ok");
  for (std::size_t i = 0; i < tables.size(); ++i) EXPECT_EQ(rowBytes(path, tables[i]), before[i]) << tables[i];
  {
    SessionStore store(path);
    MultiSessionBackend restored(opt);
    restoreStore(store, &restored, nullptr, nullptr);
    expectSameBackends(before_restore, restored);
    store.saveMaps(bigger, states, {});  // no cap in this open: the same save goes through
    std::size_t most = 0;
    for (const StoredMap& map : store.maps()) most = std::max(most, map.motions.size());
    EXPECT_EQ(most, 20000u);
  }
  EXPECT_EQ(integrityOf(path), "ok");
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
