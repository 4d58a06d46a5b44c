// SessionWorker (session/session_worker.h): the work queue and optimisation loop around a
// SessionManager, driven synchronously (offline_slam) or on its own thread (the back-end nodelet);
// keyframe_features' classified answers; HashSettings::compatible, the one rule for hashes.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <future>
#include <memory>
#include <vector>

#include "../../common/fixtures.h"
#include "../../common/scoped_temp_dir.h"
#include "../../common/sql_file.h"
#include "uw_multislam/core/session/session_worker.h"

namespace uw_multislam {
namespace core {
namespace {

SessionManagerOptions options(const std::string& store = "") {
  SessionManagerOptions o;
  o.backend.join_min_loops = 3;  // an automatic join after three global loops
  o.backend.join_policy = JoinPolicy::kCount;
  o.backend.optimise_every = 2;
  o.store_path = store;
  return o;
}

/// Keyframe k of session s on a straight line along x, its odometry 2 % long and turning a little
/// (so that loops move the optimised poses away from the odometry's).
KeyframeInput keyframe(int s, int k) {
  const Pose2 step(1.02, 0.0, 0.01);
  Pose2 pose;
  for (int i = 0; i < k; ++i) pose = compose(pose, step);
  return testing_util::keyframeInput(s, k, pose,
                                     UncertainPose2(k == 0 ? Pose2() : step, Eigen::Matrix3d::Identity() * 1e-4));
}

/// Keyframe ka of session a sees keyframe kb of session b: one metre to the side (another
/// session), or where the odometry puts it, 2 % shorter (the same session).
Loop loop(int a, int ka, int b, int kb) {
  Loop l;
  l.kind = a == b ? Loop::Kind::kLocal : Loop::Kind::kGlobal;
  l.session_a = a;
  l.keyframe_a = ka;
  l.session_b = b;
  l.keyframe_b = kb;
  Pose2 z(0.0, 1.0, 0.0);
  if (a == b) {
    const Pose2 d = between(keyframe(a, ka).odometry_pose, keyframe(b, kb).odometry_pose);
    z = Pose2(d.x() / 1.02, d.y() / 1.02, d.yaw());
  }
  l.z = UncertainPose2(z, Eigen::Matrix3d::Identity() * 1e-6);
  l.inliers = 50;
  return l;
}

/// Two sessions of 8 keyframes with loops between them, some sent before their keyframe arrives
/// (as a loop detector's may overtake the back-end's keyframes).
void feed(SessionWorker* w) {
  for (int k = 0; k < 8; ++k) ASSERT_TRUE(w->addKeyframe(keyframe(0, k)));
  ASSERT_TRUE(w->addLoop(loop(0, 1, 1, 1)));  // before session 1 exists: waits
  for (int k = 0; k < 8; ++k) {
    ASSERT_TRUE(w->addKeyframe(keyframe(1, k)));
    if (k >= 2 && k <= 6) {
      ASSERT_TRUE(w->addLoop(loop(0, k, 1, k)));
    }
  }
  ASSERT_TRUE(w->addLoop(loop(1, 0, 1, 7)));  // a local loop in the joined map
}

struct Maps {
  std::vector<std::vector<Pose2>> poses;
  std::vector<int> maps;
  std::size_t loops = 0;
};

Maps mapsOf(const SessionWorker& w) {
  return w.locked([](const SessionQueries& m) {
    Maps out;
    for (int id : m.sessionIds()) {
      out.poses.push_back(m.poses(id));
      out.maps.push_back(m.mapOf(id));
    }
    out.loops = m.loops().size();
    return out;
  });
}

TEST(SessionWorker, SynchronousAndAsynchronousDrivesGiveTheSameMaps) {
  SessionWorker sync(std::make_unique<SessionManager>(options()), SessionWorkerOptions());
  feed(&sync);
  SessionWorker async(std::make_unique<SessionManager>(options()), SessionWorkerOptions());
  std::atomic<int> after_items{0};
  async.start([&](SessionManager&) { ++after_items; });
  ASSERT_TRUE(async.asynchronous());
  feed(&async);
  async.stop();  // what is queued is processed first
  EXPECT_FALSE(async.addLoop(loop(0, 1, 1, 2))) << "an item after stop() is refused";
  EXPECT_EQ(after_items, 8 + 1 + 8 + 5 + 1);  // every item, once

  const Maps a = mapsOf(sync), b = mapsOf(async);
  ASSERT_EQ(a.maps, b.maps);
  EXPECT_EQ(a.maps, (std::vector<int>{0, 0})) << "the three global loops joined the sessions";
  EXPECT_EQ(a.loops, 7u);
  EXPECT_EQ(b.loops, 7u);
  ASSERT_EQ(a.poses.size(), b.poses.size());
  for (std::size_t s = 0; s < a.poses.size(); ++s) {
    ASSERT_EQ(a.poses[s].size(), b.poses[s].size());
    for (std::size_t k = 0; k < a.poses[s].size(); ++k) {
      EXPECT_NEAR(a.poses[s][k].x(), b.poses[s][k].x(), 1e-9) << s << ":" << k;
      EXPECT_NEAR(a.poses[s][k].y(), b.poses[s][k].y(), 1e-9) << s << ":" << k;
      EXPECT_NEAR(a.poses[s][k].yaw(), b.poses[s][k].yaw(), 1e-9) << s << ":" << k;
    }
  }
  // The worker optimised (the odometry's 2 % stretch and drift are corrected, not kept).
  EXPECT_GT(sync.stats().solves, 0);
  EXPECT_EQ(sync.stats().solves, async.stats().solves);
  const Pose2 odometry_end = keyframe(0, 7).odometry_pose;
  EXPECT_GT(std::abs(a.poses[0].back().x() - odometry_end.x()) + std::abs(a.poses[0].back().y() - odometry_end.y()),
            1e-3);
  EXPECT_EQ(sync.stats().keyframes, 16);
  EXPECT_EQ(async.stats().keyframes, 16);
  EXPECT_EQ(async.stats().pushed, 8 + 1 + 8 + 5 + 1);
  EXPECT_EQ(async.stats().queued, 0u);
}

TEST(SessionWorker, AFullQueueDropsItsOldestItemsCountedButNeverAnOptimisation) {
  SessionWorkerOptions o;
  o.queue_size = 3;
  SessionWorker w(std::make_unique<SessionManager>(options()), o);
  std::promise<void> entered, release;
  std::shared_future<void> released = release.get_future().share();
  std::atomic<int> after_items{0};
  w.start([&](SessionManager&) {
    if (after_items++ == 0) {  // the worker holds here after its first item while the others queue up
      entered.set_value();
      released.wait();
    }
  });
  std::vector<int> processed;  // under the worker's mutex (done callbacks)
  auto done = [&](const SessionQueries&, const KeyframeInput& k, const Status&) { processed.push_back(k.keyframe); };
  ASSERT_TRUE(w.addKeyframe(keyframe(0, 0), {}, done));
  ASSERT_EQ(entered.get_future().wait_for(std::chrono::seconds(30)), std::future_status::ready);
  for (int k = 1; k <= 6; ++k) ASSERT_TRUE(w.addKeyframe(keyframe(0, k), {}, done));
  w.optimiseDue();  // a priority item: not counted against the capacity, never dropped
  const SessionWorkerStats queued = w.stats();
  EXPECT_EQ(queued.pushed, 7);
  EXPECT_EQ(queued.dropped_queue_full, 3);  // keyframes 1, 2 and 3
  EXPECT_EQ(queued.queued, 3u + 1u);
  release.set_value();
  w.stop();
  EXPECT_EQ(processed, (std::vector<int>{0, 4, 5, 6}));
  EXPECT_EQ(after_items, 1 + 1 + 3);  // the first keyframe, the optimisation, the three newest
  EXPECT_EQ(w.stats().queued, 0u);
}

TEST(SessionWorker, ALoopWaitingForItsKeyframeIsAppliedWhenItArrives) {
  SessionWorker w(std::make_unique<SessionManager>(options()), SessionWorkerOptions());
  for (int k = 0; k < 4; ++k) w.addKeyframe(keyframe(0, k));
  w.addLoop(loop(0, 1, 1, 2));  // session 1's keyframe 2 has not arrived
  EXPECT_EQ(w.stats().waiting, 1u);
  EXPECT_EQ(w.locked([](const SessionQueries& m) { return m.loops().size(); }), 0u);
  w.addKeyframe(keyframe(1, 0));
  w.addKeyframe(keyframe(1, 1));
  EXPECT_EQ(w.stats().waiting, 1u) << "keyframe 2 is still missing";
  w.addKeyframe(keyframe(1, 2));
  EXPECT_EQ(w.stats().waiting, 0u);
  const std::vector<Loop> loops = w.locked([](const SessionQueries& m) { return m.loops(); });
  ASSERT_EQ(loops.size(), 1u);
  EXPECT_EQ(loops[0].keyframe_b, 2);
  EXPECT_EQ(w.stats().loops, 1) << "a retried loop counts once";
  EXPECT_EQ(w.stats().waiting_dropped, 0);
}

TEST(SessionWorker, WaitingLoopsPastTheBoundAreDroppedOldestFirstAndCounted) {
  SessionWorkerOptions o;
  o.max_waiting_loops = 2;
  SessionWorker w(std::make_unique<SessionManager>(options()), o);
  for (int k = 0; k < 4; ++k) w.addKeyframe(keyframe(0, k));
  for (int k = 0; k < 3; ++k) w.addLoop(loop(0, k, 1, k));  // session 1 not there yet
  EXPECT_EQ(w.stats().waiting, 2u);
  EXPECT_EQ(w.stats().waiting_dropped, 1);
  for (int k = 0; k < 3; ++k) w.addKeyframe(keyframe(1, k));
  EXPECT_EQ(w.stats().waiting, 0u);
  const std::vector<Loop> loops = w.locked([](const SessionQueries& m) { return m.loops(); });
  ASSERT_EQ(loops.size(), 2u) << "the oldest waiting loop was dropped";
  EXPECT_EQ(loops[0].keyframe_b, 1);
  EXPECT_EQ(loops[1].keyframe_b, 2);
}

TEST(SessionWorker, AMapChangedDuringItsSolveIsSolvedAgain) {
  SessionWorkerOptions o;
  SessionWorker* self = nullptr;
  int solves = 0;
  // The first solve changes the map meanwhile, as a service would: possible only because the
  // worker solves WITHOUT its lock (else this would deadlock).
  o.solve = [&](MapOptimisation* job) {
    if (solves++ == 0) self->locked([](SessionManager& m) { ASSERT_TRUE(m.addLoop(loop(0, 1, 0, 6)).ok()); });
    SessionManager::solveOptimisation(job);
  };
  SessionWorker w(std::make_unique<SessionManager>(options()), o);
  self = &w;
  for (int k = 0; k < 8; ++k) w.addKeyframe(keyframe(0, k));
  w.addLoop(loop(0, 0, 0, 5));
  EXPECT_EQ(solves, 0) << "one loop pending of optimise_every 2";
  w.addLoop(loop(0, 2, 0, 7));  // the second: the map is due, solved; the loop added meanwhile
  EXPECT_EQ(solves, 2);
  EXPECT_EQ(w.stats().solves, 2);
  EXPECT_EQ(w.stats().solved_again, 1);
  w.locked([](SessionManager& m) {
    EXPECT_EQ(m.view().backendStats().optimisations_discarded, 1);
    int maps = -1;
    ASSERT_TRUE(m.optimisePending(&maps).ok());
    EXPECT_EQ(maps, 0) << "the second solve took the loop added during the first";
    EXPECT_TRUE(m.nextOptimisation() == std::nullopt);
  });
}

TEST(SessionWorker, SynchronousFailuresReachTheCaller) {
  SessionWorker w(std::make_unique<SessionManager>(options()), SessionWorkerOptions());
  Status st = Status::Ok();
  w.addKeyframe(keyframe(0, 0));
  KeyframeInput bad = keyframe(0, 1);
  bad.camera.fx = -1;  // not a camera: refused, counted by the manager
  w.addKeyframe(bad, {}, [&](const SessionQueries&, const KeyframeInput&, const Status& s) { st = s; });
  EXPECT_EQ(st.code, StatusCode::kInvalidArgument);
  EXPECT_THROW(w.locked([](SessionManager&) -> int { throw std::runtime_error("boom"); }), std::runtime_error);
  SessionWorkerOptions no_queue;
  no_queue.queue_size = 0;
  EXPECT_THROW(SessionWorker(std::make_unique<SessionManager>(options()), no_queue), std::invalid_argument);
  SessionWorkerOptions raised;
  raised.nice = -1;  // a worker may only yield the cores, not take them
  EXPECT_THROW(SessionWorker(std::make_unique<SessionManager>(options()), raised), std::invalid_argument);
}

TEST(SessionWorker, AnotherVehiclesHashesAreTakenOnlyWithComparableSettings) {
  SessionWorker w(std::make_unique<SessionManager>(options()), SessionWorkerOptions());
  const HashSettings ours = w.locked([](const SessionQueries& m) { return m.hashSettings(); });
  HashSettings orb = ours;
  orb.features = FeatureType::kOrb;
  Status refused = Status::Ok();
  w.addForeignKeyframe("auv_b", orb, keyframe(0, 0),
                       [&](const SessionQueries&, const KeyframeInput&, const Status& s, int, bool) { refused = s; });
  EXPECT_EQ(refused.code, StatusCode::kFailedPrecondition);
  EXPECT_NE(refused.message.find("orb features"), std::string::npos) << refused.message;
  int local = -1;
  bool opened = false;
  w.addForeignKeyframe("auv_b", ours, keyframe(0, 0),
                       [&](const SessionQueries&, const KeyframeInput&, const Status& s, int id, bool o) {
                         ASSERT_TRUE(s.ok()) << s.message;
                         local = id;
                         opened = o;
                       });
  EXPECT_EQ(local, 0);
  EXPECT_TRUE(opened);
  Status ended = Status::Ok();
  w.endForeignSession("auv_b", 0, 1.0, [&](const SessionQueries&, const Status& s) { ended = s; });
  EXPECT_TRUE(ended.ok()) << ended.message;
  w.endForeignSession("auv_b", 0, 1.0, [&](const SessionQueries&, const Status& s) { ended = s; });
  EXPECT_EQ(ended.code, StatusCode::kNotFound);
}

// keyframe_features: each failure with its own code, so that a loop detector knows whether to
// ask again (NOT_FOUND: not stored yet), give up (FAILED_PRECONDITION: no store) or report
// damage (DATA_LOSS).
TEST(SessionWorker, KeyframeFeaturesAnswersAreClassified) {
  {
    SessionWorker w(std::make_unique<SessionManager>(options()), SessionWorkerOptions());
    w.addKeyframe(keyframe(0, 0));
    KeyframeFeaturesAnswer a;
    EXPECT_EQ(w.keyframeFeatures(-1, 0, false, &a).code, StatusCode::kInvalidArgument);
    EXPECT_EQ(w.keyframeFeatures(0, -1, false, &a).code, StatusCode::kInvalidArgument);
    EXPECT_EQ(w.keyframeFeatures(kMaxSessionId + 1, 0, false, &a).code, StatusCode::kInvalidArgument);
    // The real reason: a huge id is out of range, not negative.
    const Status huge = w.keyframeFeatures(2147483647, 0, false, &a);
    EXPECT_NE(huge.message.find("session 2147483647, outside the ids [0, 1000000]"), std::string::npos) << huge.message;
    EXPECT_NE(w.keyframeFeatures(0, -1, false, &a).message.find("keyframe ids are >= 0"), std::string::npos);
    EXPECT_EQ(w.keyframeFeatures(0, 0, false, &a).code, StatusCode::kFailedPrecondition) << "no store";
    EXPECT_EQ(w.keyframeFeatures(0, 0, true, &a).code, StatusCode::kFailedPrecondition) << "no store";
  }
  testing_util::ScopedTempDir dir("session_worker");
  const std::string db = (dir.path() / "s.db").string();
  SessionWorker w(std::make_unique<SessionManager>(options(db)), SessionWorkerOptions());
  for (int k = 0; k < 3; ++k) {
    KeyframeInput in = keyframe(0, k);
    in.features.image_size = cv::Size(640, 480);
    for (int i = 0; i < 20; ++i) in.features.keypoints.emplace_back(cv::Point2f(10.0f * i, 5.0f * k), 1.0f);
    in.features.descriptors = cv::Mat(20, 128, CV_8U, cv::Scalar(10 + k));
    in.thumbnail = {1, 2, 3};
    w.addKeyframe(in);
  }
  KeyframeFeaturesAnswer a;
  const Status ok = w.keyframeFeatures(0, 1, false, &a);
  ASSERT_TRUE(ok.ok()) << ok.message;
  EXPECT_TRUE(a.vehicle.empty());
  EXPECT_EQ(a.session.id, 0);
  EXPECT_EQ(a.session.camera.fx, 500);
  ASSERT_EQ(a.keyframe.points.size(), 20u);
  EXPECT_FLOAT_EQ(a.keyframe.points[3].x, 30.0f);
  EXPECT_EQ(a.keyframe.descriptors.at<std::uint8_t>(0, 0), 11);
  EXPECT_TRUE(a.keyframe.thumbnail.empty()) << "features only";
  EXPECT_TRUE(w.keyframeFeatures(0, 2, true, &a).ok());
  EXPECT_EQ(w.keyframeFeatures(0, 3, true, &a).code, StatusCode::kNotFound) << "not (yet) in the store";
  EXPECT_EQ(w.keyframeFeatures(0, 3, false, &a).code, StatusCode::kNotFound);
  EXPECT_EQ(w.keyframeFeatures(4, 0, false, &a).code, StatusCode::kNotFound) << "no such session";
  // Stored but unreadable: DATA_LOSS.
  ASSERT_TRUE(testing_util::execSql(db, "UPDATE keyframes SET points = x'0102' WHERE keyframe = 2"));
  const Status damaged = w.keyframeFeatures(0, 2, false, &a);
  EXPECT_EQ(damaged.code, StatusCode::kDataLoss) << damaged.message;
  // Another vehicle's session: nothing read here, the answer says whom to ask.
  const HashSettings ours = w.locked([](const SessionQueries& m) { return m.hashSettings(); });
  int local = -1;
  w.addForeignKeyframe("auv_b", ours, keyframe(7, 0),
                       [&](const SessionQueries&, const KeyframeInput&, const Status&, int id, bool) { local = id; });
  ASSERT_GT(local, 0);
  KeyframeFeaturesAnswer theirs;
  ASSERT_TRUE(w.keyframeFeatures(local, 0, false, &theirs).ok());
  EXPECT_EQ(theirs.vehicle, "auv_b");
  EXPECT_EQ(theirs.remote_session, 7);
  EXPECT_TRUE(theirs.keyframe.points.empty());
}

TEST(SessionWorker, TheHandoverListFollowsReloadsAndUnloads) {
  testing_util::ScopedTempDir dir("session_worker");
  const std::string db = (dir.path() / "s.db").string();
  {
    SessionWorker w(std::make_unique<SessionManager>(options(db)), SessionWorkerOptions());
    for (int s = 0; s < 2; ++s)
      for (int k = 0; k < 3; ++k) {
        KeyframeInput in = keyframe(s, k);
        in.features.image_size = cv::Size(640, 480);
        for (int i = 0; i < 5; ++i) in.features.keypoints.emplace_back(cv::Point2f(i, k), 1.0f);
        in.features.descriptors = cv::Mat(5, 128, CV_8U, cv::Scalar(3));
        w.addKeyframe(in);
      }
  }
  for (const bool paging : {false, true}) {
    SessionWorkerOptions o;
    o.page_stored = paging;
    SessionWorker w(std::make_unique<SessionManager>(options(db)), o);
    ReloadedSession r;
    std::vector<int> sent_features;
    const Status st = w.reloadSession("1", &r, [&](const ReloadedSession& s, const StoredKeyframe& k) {
      sent_features.push_back(static_cast<int>(k.points.size()));
      EXPECT_EQ(s.id, 1);
    });
    ASSERT_TRUE(st.ok()) << st.message;
    EXPECT_EQ(sent_features, paging ? std::vector<int>(3, 0) : std::vector<int>(3, 5)) << "paging " << paging;
    EXPECT_EQ(w.handedOver(), std::vector<int>{1});
    EXPECT_EQ(w.reloadStored().first, 1) << "session 0 still unloaded";
    EXPECT_EQ(w.handedOver(), (std::vector<int>{1, 0}));
    std::vector<std::pair<int, int>> handed;  // (session, features)
    HandoverStats h = w.handOver("test", [&](const ReloadedSession& s, const StoredKeyframe& k) {
      handed.emplace_back(s.id, static_cast<int>(k.points.size()));
    });
    EXPECT_EQ(h.subscribers, 1);
    EXPECT_EQ(h.total, 6);
    EXPECT_EQ(h.sent, 6);
    ASSERT_EQ(handed.size(), 6u);
    EXPECT_EQ(handed.front(), std::make_pair(1, paging ? 0 : 5));
    EXPECT_EQ(handed.back(), std::make_pair(0, paging ? 0 : 5));
    w.forgetHandedOver(1);  // unloaded: later subscribers do not get it
    handed.clear();
    h = w.handOver("test", [&](const ReloadedSession& s, const StoredKeyframe&) { handed.emplace_back(s.id, 0); });
    EXPECT_EQ(h.subscribers, 2);
    EXPECT_EQ(h.sent, 3);
    EXPECT_EQ(handed, (std::vector<std::pair<int, int>>(3, {0, 0})));
  }
}

TEST(RelocalisationTracker, SaysAChangeOnceAndResets) {
  SessionManager m(options());
  for (int k = 0; k < 3; ++k) ASSERT_TRUE(m.addKeyframe(keyframe(0, k)).ok());
  RelocalisationTracker t;
  std::string said = "x";
  EXPECT_FALSE(t.update(m.view(), 0, &said));  // no stored map: never relocalised
  EXPECT_TRUE(said.empty());
  EXPECT_EQ(t.state().session, 0);
  EXPECT_EQ(t.state().map, -1);
  t.published();
  EXPECT_EQ(t.state().published, 1);
  t.reset();
  EXPECT_EQ(t.state().session, -1);
  EXPECT_EQ(t.state().published, 0);
}

TEST(HashSettings, CompatibleOnlyWhenModeSeedCountAndFeatureKindAgree) {
  const HashSettings a{HashMode::kSortedDct, 7, 500, "vectors", FeatureType::kSift};
  std::string why = "untouched";
  HashSettings b = a;
  b.projections = "other text";  // the store's copy of the vectors: they follow from the seed
  EXPECT_TRUE(HashSettings::compatible(a, b, &why));
  EXPECT_EQ(why, "untouched");
  for (int change = 0; change < 4; ++change) {
    HashSettings c = a;
    if (change == 0) c.mode = HashMode::kHaloc;
    if (change == 1) c.seed = 8;
    if (change == 2) c.num_features = 499;
    if (change == 3) c.features = FeatureType::kOrb;
    EXPECT_FALSE(HashSettings::compatible(a, c, &why)) << change;
    EXPECT_FALSE(HashSettings::compatible(c, a)) << change;
    // Both sides named, a's first.
    EXPECT_NE(why.find("hash_mode sorted_dct, projection_seed 7, n = 500, sift"), std::string::npos) << why;
    EXPECT_LT(why.find("sorted_dct, projection_seed 7, n = 500, sift"), why.find(change == 0   ? "haloc"
                                                                                 : change == 1 ? "projection_seed 8"
                                                                                 : change == 2 ? "n = 499"
                                                                                               : "orb"))
        << why;
  }
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
