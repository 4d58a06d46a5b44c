// SessionManager (session/session_manager.h): one id space, requests with status codes that change
// nothing when they fail, events, and the session store behind it (restart, reload).
#include <gtest/gtest.h>

#include <algorithm>
#include <climits>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <optional>
#include <tuple>

#include "../../common/fixtures.h"
#include "../../common/scoped_temp_dir.h"
#include "../../common/seabed_features.h"
#include "../../common/sql_file.h"
#include "uw_multislam/core/export/run_outputs.h"
#include "uw_multislam/core/session/session_manager.h"
#include "uw_multislam/core/session/stored_loops.h"
#include "uw_multislam/core/store/store_merge.h"

namespace uw_multislam {
namespace core {
namespace {

SessionManagerOptions options(const std::string& store = "") {
  SessionManagerOptions o;
  o.backend.join_min_loops = 0;                // joins only when asked
  o.backend.join_policy = JoinPolicy::kCount;  // where a test turns joins on: by K loops
  o.store_path = store;
  return o;
}

KeyframeInput keyframe(int session, int k, const Pose2& pose, const Pose2& previous) {
  return testing_util::keyframeInput(session, k, pose,
                                     UncertainPose2(between(previous, pose), Eigen::Matrix3d::Identity() * 1e-4));
}

/// Session `s`: n keyframes one metre apart along x, starting at the session's origin.
void addStraightSession(SessionManager* m, int s, int n) {
  for (int k = 0; k < n; ++k) {
    const Status st = m->addKeyframe(keyframe(s, k, Pose2(k, 0, 0), Pose2(std::max(0, k - 1), 0, 0)));
    ASSERT_TRUE(st.ok()) << st.message;
  }
}

/// A global loop: keyframe ka of session a sees keyframe kb of session b at `z`.
Loop globalLoop(int a, int ka, int b, int kb, const Pose2& z) {
  Loop l;
  l.kind = Loop::Kind::kGlobal;
  l.session_a = a;
  l.keyframe_a = ka;
  l.session_b = b;
  l.keyframe_b = kb;
  l.z = UncertainPose2(z, Eigen::Matrix3d::Identity() * 1e-6);
  l.inliers = 50;
  return l;
}

/// Two straight sessions, the second one metre to the side of the first (z = (0, 1, 0) for
/// keyframe k of both), with five global loops between them.
void twoSessionsWithLoops(SessionManager* m) {
  addStraightSession(m, 0, 8);
  addStraightSession(m, 1, 8);
  for (int k = 1; k <= 5; ++k) ASSERT_TRUE(m->addLoop(globalLoop(0, k, 1, k, Pose2(0, 1, 0))).ok());
}

TEST(SessionManager, SessionsTakeTheNextIdAndIdsOnlyGrow) {
  std::vector<SessionEvent> events;
  SessionManager m(options(), [&](const SessionEvent& e) { events.push_back(e); });
  addStraightSession(&m, 0, 3);
  EXPECT_EQ(m.view().activeSession(), 0);
  addStraightSession(&m, 1, 2);  // the odometry's next session: the next id
  EXPECT_EQ(m.view().activeSession(), 1);
  EXPECT_EQ(m.view().sessionIds(), (std::vector<int>{0, 1}));
  EXPECT_EQ(m.view().nextId(), 2);
  // Session 0 ended when 1 started: its keyframes are refused as stale, nothing changes.
  const Status stale = m.addKeyframe(keyframe(0, 3, Pose2(3, 0, 0), Pose2(2, 0, 0)));
  EXPECT_EQ(stale.code, StatusCode::kFailedPrecondition);
  EXPECT_EQ(m.view().list()[0].keyframes, 3);
  EXPECT_EQ(m.view().list()[0].state, SessionState::kFinished);
  EXPECT_EQ(m.view().list()[1].state, SessionState::kActive);
  // start_session takes the next id and refuses a name in use or an old id.
  int id = -1;
  EXPECT_EQ(m.startSession("session_0", 5.0).code, StatusCode::kAlreadyExists);
  EXPECT_EQ(m.startSession("x", 5.0, 1).code, StatusCode::kInvalidArgument);
  EXPECT_EQ(m.view().activeSession(), 1);  // refused requests changed nothing
  ASSERT_TRUE(m.startSession("dive 2", 5.0, -1, &id).ok());
  EXPECT_EQ(id, 2);
  EXPECT_EQ(m.view().name(2), "dive 2");
  int started = 0, ended = 0;
  for (const SessionEvent& e : events) {
    started += e.kind == SessionEvent::Kind::kSessionStarted;
    ended += e.kind == SessionEvent::Kind::kSessionEnded;
  }
  EXPECT_EQ(started, 3);
  EXPECT_EQ(ended, 2);
}

TEST(SessionManager, AKeyframeIdFarPastTheLastIsRefusedWithoutBridging) {
  SessionManager m(options());
  addStraightSession(&m, 0, 3);
  const Status st = m.addKeyframe(keyframe(0, INT_MAX, Pose2(3, 0, 0), Pose2(2, 0, 0)));
  EXPECT_EQ(st.code, StatusCode::kInvalidArgument);
  EXPECT_NE(st.message.find("max_keyframe_gap"), std::string::npos) << st.message;
  EXPECT_EQ(m.view().list()[0].keyframes, 3);
  EXPECT_EQ(m.addKeyframe(keyframe(7, INT_MAX, Pose2(), Pose2())).code, StatusCode::kFailedPrecondition);
  EXPECT_FALSE(m.view().has(7));  // a session not opened (the next is 1), and nothing bridged
  // A small gap is bridged: placeholders at the last pose, no loop may use them.
  ASSERT_TRUE(m.addKeyframe(keyframe(0, 6, Pose2(6, 0, 0), Pose2(2, 0, 0))).ok());
  EXPECT_EQ(m.view().list()[0].keyframes, 7);
  EXPECT_EQ(m.view().stats().keyframe_gaps, 1);
  EXPECT_NEAR(m.view().poses(0)[4].x(), 2.0, 1e-9);
  EXPECT_NEAR(m.view().poses(0)[6].x(), 6.0, 1e-9);
  // A keyframe whose camera is unusable is refused before it reaches the session or the store.
  KeyframeInput no_camera = keyframe(0, 7, Pose2(7, 0, 0), Pose2(6, 0, 0));
  no_camera.camera.fx = 0;
  const Status refused = m.addKeyframe(no_camera);
  EXPECT_EQ(refused.code, StatusCode::kInvalidArgument);
  EXPECT_NE(refused.message.find("camera: focal length"), std::string::npos) << refused.message;
  EXPECT_EQ(m.view().list()[0].keyframes, 7);
  Loop onPlaceholder = globalLoop(0, 4, 0, 6, Pose2(4, 0, 0));
  onPlaceholder.kind = Loop::Kind::kLocal;
  EXPECT_EQ(m.addLoop(onPlaceholder).code, StatusCode::kFailedPrecondition);
  EXPECT_EQ(m.view().loops().size(), 0u);
}

// The store's bytes: the file and its write-ahead log (where a transaction's pages go first).
std::uintmax_t storeBytes(const std::string& db) {
  std::error_code ec;
  std::uintmax_t n = std::filesystem::file_size(db, ec);
  if (ec) n = 0;
  const std::uintmax_t wal = std::filesystem::file_size(db + "-wal", ec);
  return n + (ec ? 0 : wal);
}

// Each stored keyframe's hash blob length (keyframe order) of store session `session`.
std::vector<int> hashBytes(const std::string& db, std::int64_t session) {
  std::vector<int> out;  // through SQLite itself: the blob's length is the point
  sqlite3* h = nullptr;
  EXPECT_EQ(sqlite3_open_v2(db.c_str(), &h, SQLITE_OPEN_READONLY, nullptr), SQLITE_OK);
  sqlite3_stmt* st = nullptr;
  EXPECT_EQ(
      sqlite3_prepare_v2(h, "SELECT length(hash) FROM keyframes WHERE session = ? ORDER BY keyframe", -1, &st, nullptr),
      SQLITE_OK);
  sqlite3_bind_int64(st, 1, session);
  while (sqlite3_step(st) == SQLITE_ROW) out.push_back(sqlite3_column_int(st, 0));
  sqlite3_finalize(st);
  sqlite3_close(h);
  return out;
}

// A gap of lost keyframes is stored as minimal rows (no features, an empty hash blob) in one
// transaction: written one by one with a 1.5 kB zero hash each, a gap of 32 had cost 550 kB of
// store. Each way the rows are read back (restart, the paging read of hashes, reload, the
// features of one keyframe, merge_stores) gives the lost keyframes as they were: no features, the
// zero hash.
TEST(SessionManager, AGapIsStoredAsMinimalRowsAndReadBackEverywhere) {
  testing_util::ScopedTempDir dir("session_manager");
  const std::string db = (dir.path() / "s.db").string();
  const auto real = [](int k) {
    KeyframeInput in = keyframe(0, k, Pose2(k, 0, 0), Pose2(k - 1, 0, 0));
    in.hash = Eigen::VectorXf::Constant(HalocProjections::kHashSize, 0.25f);
    return in;
  };
  const int gap = SessionManagerOptions().max_keyframe_gap;  // the largest gap bridged
  std::uintmax_t before = 0, after = 0;
  {
    SessionManager m(options(db));
    for (int k = 0; k < 3; ++k) ASSERT_TRUE(m.addKeyframe(real(k)).ok());
    before = storeBytes(db);
    ASSERT_TRUE(m.addKeyframe(real(3 + gap)).ok());
    after = storeBytes(db);
    EXPECT_EQ(m.view().stats().keyframe_gaps, 1);
    ASSERT_TRUE(m.endSession(50.0).ok());
  }
  // The rows and pages of one transaction, not 32 x 17 kB (4 kB pages: the keyframes' table, its
  // covering index, the motions' table and their parents).
  EXPECT_LT(after - before, 64u * 1024u) << before << " -> " << after;
  std::vector<int> expected(3 + gap + 1, 4 * HalocProjections::kHashSize);
  for (int k = 3; k < 3 + gap; ++k) expected[k] = 0;
  EXPECT_EQ(hashBytes(db, 0), expected);
  const auto isLost = [](const StoredKeyframe& k) { return k.points.empty() && k.hash.isZero(0.0f); };
  const auto checkRows = [&](const std::vector<StoredKeyframe>& rows, const std::string& how) {
    ASSERT_EQ(rows.size(), expected.size()) << how;
    for (std::size_t k = 0; k < rows.size(); ++k) {
      ASSERT_EQ(rows[k].hash.size(), HalocProjections::kHashSize) << how << " " << k;
      EXPECT_EQ(isLost(rows[k]), expected[k] == 0) << how << " " << k;
      EXPECT_EQ(rows[k].hash.isZero(0.0f), expected[k] == 0) << how << " " << k;
    }
  };
  {
    SessionStore store(db, StoreAccess::kReadOnly);
    checkRows(store.keyframes(0, SessionStore::KeyframeColumns::kAll), "all columns");
    checkRows(store.keyframes(0, SessionStore::KeyframeColumns::kHash), "hashes (paging)");
    EXPECT_EQ(store.keyframeFeatures(0, 4).points.size(), 0u);
    EXPECT_EQ(store.odometry(0).size(), expected.size() - 1);
  }
  {
    SessionManager again(options(db));  // a restart
    ASSERT_EQ(again.view().list().size(), 1u);
    EXPECT_EQ(again.view().list()[0].keyframes, static_cast<int>(expected.size()));
    ReloadedSession r;
    ASSERT_TRUE(again.reload("0", &r, SessionManager::ReloadRead::kHashes).ok());
    checkRows(r.keyframes, "reload");
  }
  const std::string merged = (dir.path() / "m.db").string();
  const MergeReport report = mergeStores(merged, {{db, "auv", ""}}, SlamConfig(), false);
  EXPECT_EQ(report.keyframes, static_cast<int>(expected.size()));
  SessionStore out(merged, StoreAccess::kReadOnly);
  ASSERT_EQ(out.sessions().size(), 1u);
  const std::int64_t id = out.sessions()[0].id;
  EXPECT_EQ(hashBytes(merged, id), expected);
  checkRows(out.keyframes(id, SessionStore::KeyframeColumns::kAll), "merged");
}

// Keyframe ids that jump past max_keyframe_gap: the jumping keyframe alone is refused (a corrupt
// id must not start a session), and when the next one continues from it, the odometry's ids
// really moved on: the piece ends and a new session starts from the refused keyframe, as after a
// tracking loss. Nothing from the jump on is lost; the odometry's ids (keyframes and loops) keep
// naming it.
TEST(SessionManager, AJumpPastTheGapBoundEndsThePieceAndLosesNothingAfterIt) {
  testing_util::ScopedTempDir dir("session_manager");
  const std::string db = (dir.path() / "s.db").string();
  {
    SessionManager m(options(db));
    addStraightSession(&m, 0, 3);
    const Status jump = m.addKeyframe(keyframe(0, 1003, Pose2(3, 0, 0), Pose2(2, 0, 0)));
    EXPECT_EQ(jump.code, StatusCode::kInvalidArgument);
    EXPECT_NE(jump.message.find("max_keyframe_gap"), std::string::npos) << jump.message;
    EXPECT_FALSE(m.view().has(1));
    ASSERT_TRUE(m.addKeyframe(keyframe(0, 1004, Pose2(4, 0, 0), Pose2(3, 0, 0))).ok());
    ASSERT_TRUE(m.view().has(1));
    EXPECT_EQ(m.view().list()[0].keyframes, 3);
    EXPECT_EQ(m.view().list()[1].keyframes, 2);  // 1003 and 1004: its 0 and 1
    EXPECT_EQ(m.view().stats().keyframe_jumps, 1);
    EXPECT_EQ(m.view().stats().keyframes_refused, 1);
    // A gap after the jump is bridged from the jumping keyframe's odometry pose.
    ASSERT_TRUE(m.addKeyframe(keyframe(0, 1007, Pose2(7, 0, 0), Pose2(4, 0, 0))).ok());
    EXPECT_EQ(m.view().list()[1].keyframes, 5);
    EXPECT_NEAR(m.view().poses(1)[4].x() - m.view().poses(1)[0].x(), 4.0, 1e-6);
    // A loop in the odometry's ids: keyframe 1007 of its session 0 is keyframe 4 of session 1.
    ASSERT_TRUE(m.addLoop(globalLoop(0, 1, 0, 1007, Pose2(0, 1, 0))).ok());
    ASSERT_EQ(m.view().loops().size(), 1u);
    EXPECT_EQ(m.view().loops()[0].session_b, 1);
    EXPECT_EQ(m.view().loops()[0].keyframe_b, 4);
    // A lone corrupt id inside the new piece: refused, dropped when the next keyframe does not
    // continue from it, no new session.
    EXPECT_EQ(m.addKeyframe(keyframe(0, 99999, Pose2(8, 0, 0), Pose2(7, 0, 0))).code, StatusCode::kInvalidArgument);
    ASSERT_TRUE(m.addKeyframe(keyframe(0, 1008, Pose2(8, 0, 0), Pose2(7, 0, 0))).ok());
    EXPECT_FALSE(m.view().has(2));
    EXPECT_EQ(m.view().list()[1].keyframes, 6);
    EXPECT_EQ(m.view().stats().keyframe_jumps, 1);
    EXPECT_EQ(m.view().stats().keyframes_refused, 2);
    // A keyframe of the odometry's session from before the jump: the finished piece's, stale.
    EXPECT_EQ(m.addKeyframe(keyframe(0, 3, Pose2(3, 0, 0), Pose2(2, 0, 0))).code, StatusCode::kFailedPrecondition);
    // The odometry's next session takes id 1, the piece's: a session of its own, 2 here.
    addStraightSession(&m, 1, 2);
    ASSERT_TRUE(m.view().has(2));
    EXPECT_EQ(m.view().list()[1].keyframes, 6);
    EXPECT_EQ(m.view().list()[2].keyframes, 2);
  }
  SessionStore store(db, StoreAccess::kReadOnly);
  ASSERT_EQ(store.sessions().size(), 3u);
  EXPECT_EQ(store.keyframes(0, false).size(), 3u);
  EXPECT_EQ(store.keyframes(1, false).size(), 6u);
  EXPECT_EQ(store.loops().size(), 1u);
}

// Two jumps in one odometry session: every piece keeps its names (a loop from the second piece to
// the first is not read as one to the odometry's original session), and the odometry's next
// session that takes a finished piece's id is still a session of its own, not a stale one.
TEST(SessionManager, TwoJumpsKeepEveryPiecesNamesAndAFinishedPiecesIdStillNamesANewSession) {
  testing_util::ScopedTempDir dir("session_manager");
  SessionManager m(options((dir.path() / "s.db").string()));
  addStraightSession(&m, 0, 3);
  EXPECT_EQ(m.addKeyframe(keyframe(0, 1003, Pose2(3, 0, 0), Pose2(2, 0, 0))).code, StatusCode::kInvalidArgument);
  ASSERT_TRUE(m.addKeyframe(keyframe(0, 1004, Pose2(4, 0, 0), Pose2(3, 0, 0))).ok());
  EXPECT_EQ(m.addKeyframe(keyframe(0, 5004, Pose2(5, 0, 0), Pose2(4, 0, 0))).code, StatusCode::kInvalidArgument);
  ASSERT_TRUE(m.addKeyframe(keyframe(0, 5005, Pose2(6, 0, 0), Pose2(5, 0, 0))).ok());
  ASSERT_TRUE(m.view().has(2));
  EXPECT_EQ(m.view().stats().keyframe_jumps, 2);
  EXPECT_EQ(m.view().list()[1].keyframes, 2);  // 1003, 1004
  EXPECT_EQ(m.view().list()[2].keyframes, 2);  // 5004, 5005
  // The odometry's keyframe 1004 is the first piece's 1, its 5005 the second piece's 1.
  bool waiting = true;
  ASSERT_TRUE(m.addLoop(globalLoop(0, 1004, 0, 5005, Pose2(0, 1, 0)), &waiting).ok());
  EXPECT_FALSE(waiting);
  ASSERT_EQ(m.view().loops().size(), 1u);
  EXPECT_EQ(m.view().loops()[0].session_a, 1);
  EXPECT_EQ(m.view().loops()[0].keyframe_a, 1);
  EXPECT_EQ(m.view().loops()[0].session_b, 2);
  EXPECT_EQ(m.view().loops()[0].keyframe_b, 1);
  // The second piece finished, then the odometry's next session takes id 1 (the first piece's,
  // also finished): a session of its own, 3 here, every keyframe kept.
  ASSERT_TRUE(m.endSession(10.0).ok());
  addStraightSession(&m, 1, 3);
  ASSERT_TRUE(m.view().has(3));
  EXPECT_EQ(m.view().list()[1].keyframes, 2);
  EXPECT_EQ(m.view().list()[3].keyframes, 3);
  EXPECT_EQ(m.view().stats().keyframes_stale, 0);
}

// Keyframe 0 lost on the way: the placeholder origin opens the session's store row, which gets the
// camera of the keyframe that did arrive (it got a 0x0 camera, and export_survey --images then left
// every folder out as "of another size").
TEST(SessionManager, APlaceholderOriginStoresTheSessionsCamera) {
  testing_util::ScopedTempDir dir("session_manager");
  const std::string db = (dir.path() / "s.db").string();
  {
    SessionManager m(options(db));
    ASSERT_TRUE(m.addKeyframe(keyframe(0, 1, Pose2(1, 0, 0), Pose2(0, 0, 0))).ok());
    ASSERT_TRUE(m.addKeyframe(keyframe(0, 2, Pose2(2, 0, 0), Pose2(1, 0, 0))).ok());
    EXPECT_EQ(m.view().stats().store_failures, 0);
  }
  const SessionStore store(db, StoreAccess::kReadOnly);
  const std::vector<StoredSession> sessions = store.sessions();
  ASSERT_EQ(sessions.size(), 1u);
  EXPECT_EQ(sessions[0].camera.width, 640);
  EXPECT_EQ(sessions[0].camera.height, 480);
  EXPECT_DOUBLE_EQ(sessions[0].camera.fx, 500.0);
  EXPECT_DOUBLE_EQ(sessions[0].camera.cy, 240.0);
  EXPECT_EQ(store.keyframes(sessions[0].id).size(), 3u);
}

// start_session, then the maps saved (a flush, another map's optimisation) before the session's
// first keyframe: no row yet; the first keyframe makes it, with the session's camera (a row made
// by the save kept 0x0, and the session's loops could not be verified after a restart). A store
// that still holds such a row says so when the session is reloaded.
TEST(SessionManager, ARowMadeBeforeTheFirstKeyframeGetsItsCamera) {
  testing_util::ScopedTempDir dir("session_manager");
  const std::string db = (dir.path() / "s.db").string();
  {
    SessionManager m(options(db));
    addStraightSession(&m, 0, 3);
    ASSERT_TRUE(m.endSession(3.5).ok());
    int b = -1;
    ASSERT_TRUE(m.startSession("b", 10.0, -1, &b).ok());
    m.flush();
    {
      const SessionStore store(db, StoreAccess::kReadOnly);
      EXPECT_EQ(store.sessions().size(), 1u);  // nothing of b before its first keyframe
    }
    addStraightSession(&m, b, 3);
    EXPECT_EQ(m.view().stats().store_failures, 0);
  }
  {
    const SessionStore store(db, StoreAccess::kReadOnly);
    const std::vector<StoredSession> sessions = store.sessions();
    ASSERT_EQ(sessions.size(), 2u);
    EXPECT_EQ(sessions[1].name, "b");
    EXPECT_EQ(sessions[1].camera, keyframe(1, 0, Pose2(), Pose2()).camera);
    EXPECT_EQ(store.keyframes(sessions[1].id).size(), 3u);
  }
  // An older store: the row still 0x0. Reloading the session says that its loops cannot verify.
  ASSERT_TRUE(testing_util::execSql(db,
                                    "UPDATE sessions SET cam_width = 0, cam_height = 0, cam_fx = 0, cam_fy = 0, "
                                    "cam_cx = 0, cam_cy = 0 WHERE name = 'b'"));
  std::vector<std::string> log;
  SessionManager again(options(db), {}, [&](const std::string& line) { log.push_back(line); });
  ReloadedSession r;
  ASSERT_TRUE(again.reload("b", &r, SessionManager::ReloadRead::kHashes).ok());
  EXPECT_EQ(r.keyframes.size(), 3u);
  EXPECT_NE(std::find(log.begin(), log.end(),
                      "session 1 'b' has no stored camera (0x0, written by an older version): no loop to its 3 "
                      "keyframes can be verified"),
            log.end());
  ASSERT_TRUE(again.reload("session_0", &r, SessionManager::ReloadRead::kHashes).ok());
  EXPECT_EQ(std::count_if(log.begin(), log.end(),
                          [](const std::string& l) { return l.find("no stored camera") != std::string::npos; }),
            1);
}

TEST(SessionManager, LoopsOnKeyframesNotYetArrivedWait) {
  SessionManager m(options());
  addStraightSession(&m, 0, 3);
  bool waiting = false;
  EXPECT_FALSE(m.addLoop(globalLoop(0, 1, 1, 0, Pose2(0, 1, 0)), &waiting).ok());
  EXPECT_TRUE(waiting);
  addStraightSession(&m, 1, 1);
  EXPECT_TRUE(m.addLoop(globalLoop(0, 1, 1, 0, Pose2(0, 1, 0)), &waiting).ok());
  EXPECT_FALSE(waiting);
  EXPECT_EQ(m.view().list()[1].loops, 1);
}

TEST(SessionManager, JoinAndSplitAnswerInSessionIdsAndFailedRequestsChangeNothing) {
  std::vector<SessionEvent> events;
  SessionManager m(options(), [&](const SessionEvent& e) { events.push_back(e); });
  twoSessionsWithLoops(&m);
  EXPECT_EQ(m.join(0, 42).code, StatusCode::kNotFound);
  EXPECT_EQ(m.join(0, 1, -1).code, StatusCode::kInvalidArgument);
  const Status six = m.join(0, 1, 6);
  EXPECT_EQ(six.code, StatusCode::kFailedPrecondition) << six.message;  // 5 loops only
  EXPECT_EQ(m.view().mapIds(), (std::vector<int>{0, 1}));
  ASSERT_TRUE(m.join(0, 1, 5).ok());
  EXPECT_EQ(m.view().mapOf(1), 0);
  ASSERT_EQ(m.view().links().size(), 1u);
  EXPECT_EQ(m.view().links()[0].previous, 0);
  EXPECT_EQ(m.view().links()[0].current, 1);
  // Session 1's keyframe k lies one metre to the side of session 0's keyframe k.
  const std::vector<Pose2> p0 = m.view().poses(0), p1 = m.view().poses(1);
  for (int k = 0; k < 8; ++k) {
    EXPECT_NEAR(p1[k].x(), p0[k].x(), 1e-6) << k;
    EXPECT_NEAR(p1[k].y(), p0[k].y() + 1.0, 1e-6) << k;
  }
  EXPECT_EQ(m.split(42).code, StatusCode::kNotFound);
  EXPECT_EQ(m.split(-1).code, StatusCode::kInvalidArgument);  // outside the ids: said so
  EXPECT_EQ(m.join(0, INT_MAX).code, StatusCode::kInvalidArgument);
  ASSERT_TRUE(m.split(1).ok());
  EXPECT_EQ(m.view().mapOf(1), 1);
  const Status again = m.split(1);
  EXPECT_EQ(again.code, StatusCode::kFailedPrecondition) << again.message;
  bool joined = false, split = false;
  for (const SessionEvent& e : events) {
    joined |= e.kind == SessionEvent::Kind::kMapsJoined;
    split |= e.kind == SessionEvent::Kind::kMapSplit;
  }
  EXPECT_TRUE(joined && split);
}

TEST(SessionManager, TheStoreBringsBackSessionsIdsMapsAndLoopsAndReloadHandsBackKeyframes) {
  testing_util::ScopedTempDir dir("session_manager");
  const std::string db = (dir.path() / "s.db").string();
  std::vector<Pose2> joined;
  {
    SessionManager m(options(db));
    twoSessionsWithLoops(&m);
    ASSERT_TRUE(m.join(0, 1, 5).ok());
    joined = m.view().poses(1);
    // A session opened by start_session that no keyframe follows must not stop the maps from
    // being saved (it used to: the join was lost at the next start).
    ASSERT_TRUE(m.startSession("empty", 20.0).ok());
    ASSERT_TRUE(m.endSession(21.0).ok());
    ASSERT_TRUE(m.split(1).ok());
    ASSERT_TRUE(m.join(0, 1, 5).ok());
    EXPECT_EQ(m.view().stats().store_failures, 0);
  }
  std::vector<std::string> log;
  SessionManager again(options(db), {}, [&](const std::string& line) { log.push_back(line); });
  ASSERT_EQ(again.view().restoredSessions(), 2);
  // The start-up log names what an earlier run left.
  EXPECT_NE(std::find(log.begin(), log.end(),
                      "restored sessions: 0 'session_0' (8 keyframes, map 0), 1 'session_1' (8 keyframes, map 0)"),
            log.end());
  const std::vector<SessionSummary> list = again.view().list();
  ASSERT_EQ(list.size(), 2u);
  EXPECT_EQ(list[0].state, SessionState::kUnloaded);
  EXPECT_EQ(list[1].map, 0);  // still joined after the restart
  EXPECT_EQ(list[1].keyframes, 8);
  EXPECT_EQ(list[1].loops, 5);
  const std::vector<Pose2> back = again.view().poses(1);
  for (std::size_t k = 0; k < back.size(); ++k) EXPECT_NEAR(back[k].y(), joined[k].y(), 1e-9) << k;
  // Session 2 ('empty') never had a keyframe: nothing of it was stored, so the store never held
  // its id, and this run may give it again.
  EXPECT_EQ(again.view().nextId(), 2);
  EXPECT_EQ(again.view().firstNewId(), 2);
  EXPECT_TRUE(again.view().restored(1));
  EXPECT_FALSE(again.view().restored(2));
  // The frames session 1 was made from are recognised (a folder run into the store again).
  std::vector<FrameRecord> frames;
  for (int k = 0; k < 8; ++k) frames.push_back({10 * k, "", 100.0 + k, 2.0});
  EXPECT_EQ(again.view().storedSessionsOf(frames), std::vector<int>{1});
  frames[3].stamp_s += 0.5;  // other stamps: another recording
  EXPECT_TRUE(again.view().storedSessionsOf(frames).empty());
  ReloadedSession r;
  EXPECT_EQ(again.reload("nope", &r).code, StatusCode::kNotFound);
  ASSERT_TRUE(again.reload("1", &r).ok());
  EXPECT_EQ(r.id, 1);
  EXPECT_EQ(r.keyframes.size(), 8u);
  EXPECT_EQ(r.camera.width, 640);
  EXPECT_EQ(again.reload("session_1", &r).code, StatusCode::kAlreadyExists);
  EXPECT_EQ(again.view().list()[1].state, SessionState::kFinished);
  // unload_session: back to UNLOADED, in its map with its loops, and reload brings it back.
  int id = -1;
  EXPECT_EQ(again.unload("0", &id).code, StatusCode::kFailedPrecondition);  // never reloaded
  EXPECT_EQ(id, 0);
  EXPECT_EQ(again.unload("nope", &id).code, StatusCode::kNotFound);
  ASSERT_TRUE(again.unload("session_1", &id).ok());
  EXPECT_EQ(id, 1);
  EXPECT_EQ(again.view().list()[1].state, SessionState::kUnloaded);
  EXPECT_EQ(
      (std::vector<int>{again.view().list()[1].map, again.view().list()[1].keyframes, again.view().list()[1].loops}),
      (std::vector<int>{0, 8, 5}));
  const Status twice = again.unload("1");
  EXPECT_EQ(twice.code, StatusCode::kFailedPrecondition);
  EXPECT_NE(twice.message.find("not loaded"), std::string::npos) << twice.message;
  ASSERT_TRUE(again.reload("1", &r).ok());
  EXPECT_EQ(r.keyframes.size(), 8u);
  EXPECT_EQ(again.view().list()[1].state, SessionState::kFinished);
  // Reloaded reading nothing (the back-end's ~reload_stored: the hashes are handed over later),
  // or the hashes only; loaded all the same.
  ASSERT_TRUE(again.unload("1").ok());
  ASSERT_TRUE(again.reload("1", &r, SessionManager::ReloadRead::kNothing).ok());
  EXPECT_TRUE(r.keyframes.empty());
  EXPECT_EQ(again.view().list()[1].state, SessionState::kFinished);
  EXPECT_EQ(again.view().storedHashes(1).size(), 8u);
  EXPECT_EQ(again.reload("1", &r, SessionManager::ReloadRead::kNothing).code, StatusCode::kAlreadyExists);
  ASSERT_TRUE(again.unload("1").ok());
  ASSERT_TRUE(again.reload("1", &r, SessionManager::ReloadRead::kHashes).ok());
  ASSERT_EQ(r.keyframes.size(), 8u);
  EXPECT_EQ(r.keyframes[3].hash.size(), 384);
  EXPECT_TRUE(r.keyframes[3].points.empty());
  // New sessions continue after the stored ones.
  addStraightSession(&again, again.view().nextId(), 2);
  EXPECT_EQ(again.view().activeSession(), 2);
  const Status live = again.unload("2");
  EXPECT_EQ(live.code, StatusCode::kFailedPrecondition);  // recorded in this run
  EXPECT_NE(live.message.find("recorded in this run"), std::string::npos) << live.message;
  EXPECT_EQ(again.view().list()[2].state, SessionState::kActive);
  SessionManager none(options());
  EXPECT_EQ(none.reload("0", &r).code, StatusCode::kFailedPrecondition);
  EXPECT_EQ(none.unload("0").code, StatusCode::kFailedPrecondition);
}

// A new session's first keyframe that closes loops (offline: they come with the keyframe) stores
// them with the session's store row, which is made by that same keyframe. They used to be
// converted to store ids before the row existed: stored with session -1, dropped at the restart
// (seen on the demo survey: 1 of 38 global loops).
TEST(SessionManager, LoopsClosedByANewSessionsFirstKeyframeSurviveARestart) {
  testing_util::ScopedTempDir dir("session_manager");
  const std::string db = (dir.path() / "s.db").string();
  {
    SessionManager m(options(db));
    addStraightSession(&m, 0, 8);
    const std::vector<Loop> at_origin{globalLoop(0, 3, 1, 0, Pose2(0, 1, 0)), globalLoop(0, 4, 1, 0, Pose2(-1, 1, 0))};
    ASSERT_TRUE(m.addKeyframe(keyframe(1, 0, Pose2(), Pose2()), at_origin).ok());
    ASSERT_TRUE(m.addKeyframe(keyframe(1, 1, Pose2(1, 0, 0), Pose2())).ok());
    ASSERT_TRUE(m.endSession(102.0).ok());
    EXPECT_EQ(m.view().stats().store_failures, 0);
    ASSERT_EQ(m.view().loops().size(), 2u);
  }
  SessionManager again(options(db));
  ASSERT_EQ(again.view().restoredSessions(), 2);
  ASSERT_EQ(again.view().loops().size(), 2u);
  for (const Loop& l : again.view().loops()) {
    EXPECT_EQ(l.session_a, 0);
    EXPECT_EQ(l.session_b, 1);
    EXPECT_EQ(l.keyframe_b, 0);
  }
  EXPECT_EQ(again.view().list()[1].loops, 2);
}

TEST(SessionManager, PositionPriorsSurviveARestartInTheirMapsFrameAndMoveOnWithAJoin) {
  testing_util::ScopedTempDir dir("session_manager");
  const std::string db = (dir.path() / "s.db").string();
  const Eigen::Matrix2d cov = (Eigen::Matrix2d() << 0.04, 0.01, 0.01, 0.09).finished();
  Pose2 kf3;
  {
    SessionManager m(options(db));
    addStraightSession(&m, 0, 6);
    addStraightSession(&m, 1, 6);  // ends session 0
    ASSERT_TRUE(m.addPositionPrior(0, 3, Eigen::Vector2d(3.0, 0.4), cov).ok());
    ASSERT_TRUE(m.addPositionPrior(1, 2, Eigen::Vector2d(2.0, -0.3), cov).ok());
    EXPECT_EQ(m.addPositionPrior(0, 0, Eigen::Vector2d(0.0, 0.0), cov).code, StatusCode::kFailedPrecondition);
    EXPECT_EQ(m.addPositionPrior(0, 9, Eigen::Vector2d(0.0, 0.0), cov).code, StatusCode::kNotFound);
    ASSERT_TRUE(m.endSession(106.0).ok());  // the maps saved, the priors with them
    kf3 = m.view().poses(0)[3];
    EXPECT_GT(kf3.y(), 1e-3);  // pulled toward the prior (odometry of 1 cm per metre: a few mm)
  }
  SessionManager again(options(db));
  const std::vector<PriorRecord> priors = again.view().positionPriors();
  ASSERT_EQ(priors.size(), 2u);
  EXPECT_EQ(priors[0].session, 0);
  EXPECT_EQ(priors[0].keyframe, 3);
  EXPECT_EQ(priors[0].position, Eigen::Vector2d(3.0, 0.4));
  EXPECT_EQ(priors[0].covariance, cov);
  EXPECT_EQ(priors[1].session, 1);
  EXPECT_EQ(priors[1].position, Eigen::Vector2d(2.0, -0.3));
  EXPECT_TRUE(approxEqual(again.view().poses(0)[3], kf3, 1e-9, 1e-9));
  // Joined into session 0's map (session 1 one metre to the side), session 1's prior moves into
  // map 0's frame with its keyframes, and is saved there.
  for (int k = 1; k <= 5; ++k) ASSERT_TRUE(again.addLoop(globalLoop(0, k, 1, k, Pose2(0, 1, 0))).ok());
  ASSERT_TRUE(again.join(0, 1).ok());
  const std::vector<PriorRecord> joined = again.view().positionPriors();
  ASSERT_EQ(joined.size(), 2u);
  EXPECT_LT((joined[1].position - Eigen::Vector2d(2.0, 0.7)).norm(), 0.05) << joined[1].position.transpose();
  EXPECT_LT((joined[0].position - Eigen::Vector2d(3.0, 0.4)).norm(), 1e-12);
}

TEST(SessionManager, PositionPriorsReachTheStoreWhenAcceptedAndSurviveACrash) {
  // The maps are saved at joins, splits and session ends only: a fix accepted after the last of
  // those must be in the store already when the process dies, on a saved map (session 0's, saved
  // at its end) and on a session alone in its map since it started (session 1's, never saved).
  testing_util::ScopedTempDir dir("session_manager");
  const std::string db = (dir.path() / "s.db").string();
  const Eigen::Matrix2d cov = (Eigen::Matrix2d() << 0.04, 0.01, 0.01, 0.09).finished();
  {
    SessionManager m(options(db));
    addStraightSession(&m, 0, 6);
    addStraightSession(&m, 1, 6);  // ends session 0: the maps saved
    ASSERT_TRUE(m.addPositionPrior(0, 3, Eigen::Vector2d(3.0, 0.4), cov).ok());
    ASSERT_TRUE(m.addPositionPrior(1, 2, Eigen::Vector2d(2.0, -0.3), cov).ok());
    EXPECT_EQ(m.view().stats().store_failures, 0);
  }  // a crash: session 1 never ended, nothing saved the maps since session 0's end
  SessionManager again(options(db));
  const std::vector<PriorRecord> priors = again.view().positionPriors();
  ASSERT_EQ(priors.size(), 2u);
  EXPECT_EQ(priors[0].session, 0);
  EXPECT_EQ(priors[0].keyframe, 3);
  EXPECT_EQ(priors[0].position, Eigen::Vector2d(3.0, 0.4));
  EXPECT_EQ(priors[0].covariance, cov);
  EXPECT_EQ(priors[1].session, 1);
  EXPECT_EQ(priors[1].keyframe, 2);
  EXPECT_EQ(priors[1].position, Eigen::Vector2d(2.0, -0.3));
  // Both maps' stored motions are without them: optimised again, they pull toward them.
  again.flush();
  EXPECT_GT(again.view().poses(0)[3].y(), 1e-3);
  EXPECT_LT(again.view().poses(1)[2].y(), -1e-3);
}

TEST(SessionManager, DeferredOptimisationRunsOutsideRequestsAndSavesTheFinishedMap) {
  testing_util::ScopedTempDir dir("session_manager");
  const std::string db = (dir.path() / "s.db").string();
  std::vector<Pose2> optimised;
  {
    SessionManagerOptions o = options(db);
    o.backend.optimise_every = 1;
    o.backend.intra_loop_gate = false;  // the loop is 0.3 m off a 1 cm odometry on purpose: it must move the map
    int optimisations = 0;
    SessionManager m(o, [&](const SessionEvent& e) { optimisations += e.kind == SessionEvent::Kind::kMapOptimised; });
    m.setDeferredOptimisation(true);
    addStraightSession(&m, 0, 8);
    Loop l = globalLoop(0, 0, 0, 7, Pose2(7.3, 0, 0));  // the odometry says 7 m
    l.kind = Loop::Kind::kLocal;
    ASSERT_TRUE(m.addLoop(l).ok());
    EXPECT_EQ(optimisations, 0);
    EXPECT_DOUBLE_EQ(m.view().poses(0).back().x(), 7.0);  // the request did not optimise
    std::optional<MapOptimisation> job = m.nextOptimisation();
    ASSERT_TRUE(job.has_value());
    EXPECT_EQ(job->map, 0);
    SessionManager::solveOptimisation(&*job);
    addStraightSession(&m, 1, 2);  // meanwhile session 0 ends: its map's problem is unchanged
    EXPECT_TRUE(m.applyOptimisation(*job));
    EXPECT_EQ(optimisations, 1);
    EXPECT_FALSE(m.nextOptimisation().has_value());
    optimised = m.view().poses(0);
    EXPECT_GT(optimised.back().x(), 7.1);
  }  // no flush: what the store holds now is what applyOptimisation saved
  SessionManager again(options(db));
  const std::vector<Pose2> back = again.view().poses(0);
  ASSERT_EQ(back.size(), optimised.size());
  for (std::size_t k = 0; k < back.size(); ++k) EXPECT_NEAR(back[k].x(), optimised[k].x(), 1e-9) << k;
}

// add_link: an operator's loop with a measured pose. Every misuse is refused
// with its code and changes nothing; an accepted link is a loop like a detector's: it carries its
// measured pose into a join and survives a restart.
TEST(SessionManager, AManualLinkIsALoopLikeADetectorsAndAMisuseChangesNothing) {
  testing_util::ScopedTempDir dir("session_manager");
  const std::string db = (dir.path() / "s.db").string();
  {
    SessionManager m(options(db));
    addStraightSession(&m, 0, 8);
    addStraightSession(&m, 1, 3);
    ASSERT_TRUE(m.addKeyframe(keyframe(1, 7, Pose2(7, 0, 0), Pose2(2, 0, 0))).ok());  // 3..6 bridged
    auto link = [](int a, int ka, int b, int kb) { return globalLoop(a, ka, b, kb, Pose2(0, 1, 0)); };
    Loop nan = link(0, 2, 1, 2), asymmetric = nan, indefinite = nan, singular = nan, negative = nan;
    nan.z.mean = Pose2(std::nan(""), 0, 0);
    singular.z.covariance(2, 2) = 0.0;
    asymmetric.z.covariance(0, 1) = 1e-7;
    indefinite.z.covariance(2, 2) = -1e-6;
    negative.inliers = -1;
    Loop too_many = link(0, 2, 1, 2);
    too_many.inliers = 2147483647;  // more than num_features (500): no keyframe has that many features
    const std::vector<std::pair<Loop, StatusCode>> misuses{{link(0, 2, 42, 2), StatusCode::kNotFound},
                                                           {link(-1, 2, 1, 2), StatusCode::kInvalidArgument},
                                                           {link(0, 8, 1, 2), StatusCode::kNotFound},
                                                           {link(0, -1, 1, 2), StatusCode::kInvalidArgument},
                                                           {link(1, 2, 1, 2), StatusCode::kInvalidArgument},
                                                           {link(0, 2, 1, 4), StatusCode::kFailedPrecondition},
                                                           {nan, StatusCode::kInvalidArgument},
                                                           {asymmetric, StatusCode::kInvalidArgument},
                                                           {indefinite, StatusCode::kInvalidArgument},
                                                           {singular, StatusCode::kInvalidArgument},
                                                           {negative, StatusCode::kInvalidArgument},
                                                           {too_many, StatusCode::kInvalidArgument}};
    for (std::size_t i = 0; i < misuses.size(); ++i) {
      const Status st = m.addLink(misuses[i].first);
      EXPECT_EQ(st.code, misuses[i].second) << i << ": " << st.message;
      EXPECT_FALSE(st.message.empty()) << i;
      // The heads' one function (add_link, offline_slam --add-link) checks the same before adding.
      Loop l = misuses[i].first;
      EXPECT_EQ(checkOperatorLink(m.view(), SlamConfig(), false, &l, l.z.mean.yaw()).code, misuses[i].second) << i;
      EXPECT_EQ(addOperatorLink(&m, SlamConfig(), false, &l, l.z.mean.yaw()).code, misuses[i].second) << i;
    }
    {
      const Status st = m.addLink(too_many);
      EXPECT_NE(st.message.find("inliers is more than 500 (num_features"), std::string::npos) << st.message;
    }
    // A yaw out of [-pi, pi] as given (1e9 rad wraps to 0.577 rad in Pose2) is refused, naming it;
    // pi itself is an angle.
    for (const double yaw : {1e9, -3.2, 2 * M_PI}) {
      Loop l = link(0, 2, 1, 2);
      l.z.mean = Pose2(0, 1, yaw);
      const Status st = addOperatorLink(&m, SlamConfig(), false, &l, yaw);
      EXPECT_EQ(st.code, StatusCode::kInvalidArgument) << yaw;
      EXPECT_NE(st.message.find("outside [-pi, pi]"), std::string::npos) << st.message;
    }
    EXPECT_TRUE(m.view().loops().empty());
    EXPECT_EQ(m.view().list()[0].loops + m.view().list()[1].loops, 0);
    // Accepted: global between the sessions, local inside one (kind from the sessions, not the
    // request), frames filled in.
    Loop local = link(0, 1, 0, 5);
    local.z = UncertainPose2(Pose2(4, 0, 0), Eigen::Matrix3d::Identity() * 1e-6);
    local.kind = Loop::Kind::kGlobal;
    Loop given = link(0, 2, 1, 2);
    given.inliers = 500;  // num_features: possible
    ASSERT_TRUE(checkOperatorLink(m.view(), SlamConfig(), false, &given, M_PI).ok());
    EXPECT_TRUE(m.view().loops().empty()) << "a check adds nothing";
    ASSERT_TRUE(addOperatorLink(&m, SlamConfig(), false, &given, given.z.mean.yaw()).ok());
    ASSERT_TRUE(m.addLink(local).ok());
    ASSERT_EQ(m.view().loops().size(), 2u);
    EXPECT_EQ(m.view().loops()[0].kind, Loop::Kind::kGlobal);
    EXPECT_EQ(m.view().loops()[1].kind, Loop::Kind::kLocal);
    EXPECT_EQ(m.view().loops()[0].frame_b, 20);
    EXPECT_EQ(m.view().list()[0].loops, 2);
    // One link is enough for an operator's join with min_loops 1; it places session 1 one metre
    // to the side of session 0 (keyframe 2 of both).
    ASSERT_TRUE(m.join(0, 1, 1).ok());
    EXPECT_NEAR(m.view().poses(1)[2].x(), m.view().poses(0)[2].x(), 1e-6);
    EXPECT_NEAR(m.view().poses(1)[2].y(), m.view().poses(0)[2].y() + 1.0, 1e-6);
    ASSERT_TRUE(m.endSession(200.0).ok());
  }
  SessionManager again(options(db));
  ASSERT_EQ(again.view().loops().size(), 2u);
  EXPECT_EQ(again.view().mapOf(1), 0);
  EXPECT_NEAR(again.view().loops()[0].z.mean.y(), 1.0, 1e-12);
}

// optimise: maps with fewer than optimise_every loops pending wait; the
// operator's optimise solves them now (deferred: marks them due), and says when nothing waits.
TEST(SessionManager, OptimiseNowSolvesTheMapsWhoseLoopsWaitAndOnlyThose) {
  SessionManagerOptions o = options();
  o.backend.optimise_every = 100;
  o.backend.intra_loop_gate = false;  // the loop is 0.3 m off a 1 cm odometry on purpose
  SessionManager m(o);
  addStraightSession(&m, 0, 8);
  addStraightSession(&m, 1, 8);  // session 0 ends: with nothing pending, nothing to solve
  Loop l = globalLoop(1, 0, 1, 7, Pose2(7.3, 0, 0));
  l.kind = Loop::Kind::kLocal;
  ASSERT_TRUE(m.addLoop(l).ok());
  EXPECT_DOUBLE_EQ(m.view().poses(1).back().x(), 7.0);  // 1 of 100 loops: waiting
  const int before = m.view().backendStats().optimisations;
  int maps = -1;
  const Status st = m.optimisePending(&maps);
  ASSERT_TRUE(st.ok()) << st.message;
  EXPECT_EQ(maps, 1);
  EXPECT_EQ(m.view().backendStats().optimisations, before + 1);
  EXPECT_GT(m.view().poses(1).back().x(), 7.1);
  EXPECT_DOUBLE_EQ(m.view().poses(0).back().x(), 7.0);  // the other map was not touched
  const Status again = m.optimisePending(&maps);
  EXPECT_TRUE(again.ok());
  EXPECT_EQ(maps, 0);
  EXPECT_NE(again.message.find("no map"), std::string::npos) << again.message;
  EXPECT_EQ(m.view().backendStats().optimisations, before + 1);

  // Deferred (the back-end nodelet): marked due, solved by the host.
  SessionManager d(o);
  d.setDeferredOptimisation(true);
  addStraightSession(&d, 0, 8);
  Loop l0 = l;
  l0.session_a = l0.session_b = 0;
  ASSERT_TRUE(d.addLoop(l0).ok());
  EXPECT_FALSE(d.nextOptimisation().has_value());
  ASSERT_TRUE(d.optimisePending(&maps).ok());
  EXPECT_EQ(maps, 1);
  EXPECT_DOUBLE_EQ(d.view().poses(0).back().x(), 7.0);
  ASSERT_TRUE(d.nextOptimisation().has_value());

  o.backend.optimise = false;
  SessionManager off(o);
  addStraightSession(&off, 0, 2);
  EXPECT_EQ(off.optimisePending(&maps).code, StatusCode::kFailedPrecondition);
  EXPECT_EQ(maps, 0);
}

// detect_loops: every misuse is refused before anything is searched; the
// search itself is tested on real images through the service (rostest operator_services) and
// offline_slam --detect-loops (pytest test_merge_stores.py).
TEST(SessionManager, DetectLoopsIsRefusedWithNothingChangedForEveryMisuse) {
  testing_util::ScopedTempDir dir("session_manager");
  const std::string db = (dir.path() / "s.db").string();
  {
    SessionManager m(options(db));
    addStraightSession(&m, 0, 4);
    addStraightSession(&m, 1, 4);
    ASSERT_TRUE(m.endSession(200.0).ok());
  }
  SessionManager m(options(db));
  addStraightSession(&m, 2, 3);  // recorded in this run
  const SlamConfig config;
  StoredLoopSearch f;
  const std::vector<std::pair<std::vector<int>, StatusCode>> misuses{
      {{}, StatusCode::kInvalidArgument},        {{0}, StatusCode::kInvalidArgument},
      {{0, 0}, StatusCode::kInvalidArgument},    {{0, 9}, StatusCode::kNotFound},
      {{0, 2}, StatusCode::kFailedPrecondition}, {{-1, 0}, StatusCode::kNotFound}};
  for (const auto& [sessions, code] : misuses) {
    const Status st = detectStoredLoops(&m, config, sessions, &f);
    EXPECT_EQ(st.code, code) << ::testing::PrintToString(sessions) << ": " << st.message;
    EXPECT_FALSE(st.message.empty());
    EXPECT_EQ(f.queries, 0);
  }
  // add_link's find form, on the same sessions (no features stored: nothing to verify).
  const std::vector<std::pair<Loop, StatusCode>> finds{
      {globalLoop(0, 1, 9, 1, Pose2()), StatusCode::kNotFound},
      {globalLoop(0, 1, 1, 4, Pose2()), StatusCode::kNotFound},
      {globalLoop(0, -1, 1, 1, Pose2()), StatusCode::kInvalidArgument},
      {globalLoop(1, 1, 1, 1, Pose2()), StatusCode::kInvalidArgument},
      {globalLoop(0, 1, 2, 1, Pose2()), StatusCode::kFailedPrecondition},   // this run's: no features stored
      {globalLoop(0, 1, 1, 1, Pose2()), StatusCode::kFailedPrecondition}};  // no motion verified
  for (std::size_t i = 0; i < finds.size(); ++i) {
    Loop l = finds[i].first;
    const Status st = findStoredLink(m.view(), config, &l);
    EXPECT_EQ(st.code, finds[i].second) << i << ": " << st.message;
    EXPECT_FALSE(st.message.empty()) << i;
  }
  Loop unverified = globalLoop(0, 1, 1, 1, Pose2());
  EXPECT_NE(findStoredLink(m.view(), config, &unverified).message.find("no motion verified"), std::string::npos);
  SessionManager none(options());
  addStraightSession(&none, 0, 2);
  addStraightSession(&none, 1, 2);
  EXPECT_EQ(detectStoredLoops(&none, config, {0, 1}, &f).code, StatusCode::kFailedPrecondition);
  Loop without_store = globalLoop(0, 1, 1, 1, Pose2());
  EXPECT_EQ(findStoredLink(none.view(), config, &without_store).code, StatusCode::kFailedPrecondition);
  EXPECT_TRUE(m.view().loops().empty());
  EXPECT_EQ(m.view().mapIds(), (std::vector<int>{0, 1, 2}));
}

// add_link's "find it" between keyframes of this run's sessions: their features are read from the
// store, where each keyframe went as it arrived (rendered seabed frames, known poses).
class SessionManagerFeatures : public testing_util::SeabedFeaturesTest {};

TEST_F(SessionManagerFeatures, FindItMeasuresALinkBetweenThisRunsStoredKeyframes) {
  testing_util::ScopedTempDir dir("session_manager");
  SessionManager m(options((dir.path() / "s.db").string()));
  const std::vector<Pose2> a{Pose2(2.5, 3.0, 0.0), Pose2(3.7, 3.0, 0.0), Pose2(4.9, 3.0, 0.0)};
  const std::vector<Pose2> b{Pose2(4.0, 3.3, 1.2), Pose2(4.0, 4.5, 1.2)};
  auto add = [&](int s, const std::vector<Pose2>& world) {
    for (int k = 0; k < static_cast<int>(world.size()); ++k) {
      KeyframeInput in = keyframe(s, k, between(world[0], world[k]), between(world[0], world[std::max(0, k - 1)]));
      in.camera = camera_;
      in.features = features(world[k], 2.0);
      ASSERT_TRUE(m.addKeyframe(in).ok());
    }
  };
  add(0, a);
  add(1, b);  // session 1 records; session 0 ended
  Loop l = globalLoop(0, 1, 1, 0, Pose2());
  ASSERT_TRUE(m.view().inStore(0, 1) && m.view().inStore(1, 0));
  const Status st = findStoredLink(m.view(), SlamConfig(), &l);
  ASSERT_TRUE(st.ok()) << st.message;
  const Pose2 truth = between(a[1], b[0]);
  EXPECT_TRUE(approxEqual(l.z.mean, truth, 0.02, 0.01)) << l.z.mean << " vs " << truth;
  EXPECT_GE(l.inliers, 25);
  ASSERT_TRUE(m.addLink(l).ok());
  EXPECT_EQ(m.view().loops().size(), 1u);
  // A keyframe kept in memory only (localisation mode) cannot be measured: refused, said why.
  ASSERT_TRUE(m.setLocalisation(true).ok());
  KeyframeInput more = keyframe(1, 2, between(b[0], Pose2(4.0, 5.7, 1.2)), between(b[0], b[1]));
  more.camera = camera_;
  more.features = features(Pose2(4.0, 5.7, 1.2), 2.0);
  ASSERT_TRUE(m.addKeyframe(more).ok());
  ASSERT_TRUE(m.setLocalisation(false).ok());
  EXPECT_FALSE(m.view().inStore(1, 2));
  Loop memory_only = globalLoop(0, 2, 1, 2, Pose2());
  const Status refused = findStoredLink(m.view(), SlamConfig(), &memory_only);
  EXPECT_EQ(refused.code, StatusCode::kFailedPrecondition);
  EXPECT_NE(refused.message.find("keyframe 2 of session 1 is not in the store"), std::string::npos) << refused.message;
}

std::string fileBytes(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>());
}

// set_mode localisation: the store stays byte-identical while sessions are
// tracked, the requests that would change a stored map are refused, automatic joins wait; a
// session cut by the mode keeps its stored prefix and the store restores.
TEST(SessionManager, LocalisationModeWritesNothingChangesNoStoredMapAndLeavesARestorableStore) {
  testing_util::ScopedTempDir dir("session_manager");
  const std::string db = (dir.path() / "s.db").string();
  SessionManagerOptions o = options(db);
  o.backend.join_min_loops = 1;  // one global loop joins automatically (in mapping mode)
  {
    SessionManager m(o);
    addStraightSession(&m, 0, 8);
    ASSERT_TRUE(m.endSession(8.0).ok());
  }
  const std::string before = fileBytes(db);
  ASSERT_FALSE(before.empty());
  {
    SessionManager m(o);
    EXPECT_TRUE(m.setLocalisation(true).ok());
    EXPECT_TRUE(m.view().localising());
    addStraightSession(&m, 1, 5);
    Loop local = globalLoop(1, 0, 1, 4, Pose2(4, 0, 0));
    local.kind = Loop::Kind::kLocal;
    ASSERT_TRUE(m.addLoop(local).ok());
    ASSERT_TRUE(m.addLoop(globalLoop(0, 2, 1, 2, Pose2(0, 1, 0))).ok());
    EXPECT_EQ(m.view().mapIds(), (std::vector<int>{0, 1}));  // the automatic join waits
    int maps = 0;
    const std::vector<Status> refused{m.join(0, 1, 1), m.split(1), m.addLink(globalLoop(0, 3, 1, 3, Pose2(0, 1, 0))),
                                      m.optimisePending(&maps)};
    for (const Status& st : refused) {
      EXPECT_EQ(st.code, StatusCode::kFailedPrecondition) << st.message;
      EXPECT_NE(st.message.find("localisation mode"), std::string::npos) << st.message;
    }
    StoredLoopSearch f;
    const Status detect = detectStoredLoops(&m, SlamConfig(), {0, 1}, &f);
    EXPECT_EQ(detect.code, StatusCode::kFailedPrecondition);
    EXPECT_NE(detect.message.find("localisation mode"), std::string::npos) << detect.message;
    EXPECT_EQ(m.view().list()[1].keyframes, 5);  // tracked all the same
    EXPECT_EQ(m.view().loops().size(), 2u);
    ASSERT_TRUE(m.endSession(20.0).ok());
    EXPECT_EQ(m.view().stats().store_failures, 0);
  }
  EXPECT_EQ(fileBytes(db), before) << "localisation mode changed the store";
  EXPECT_FALSE(std::filesystem::exists(db + "-wal") && std::filesystem::file_size(db + "-wal") > 0);
  {
    // Mapping, then localisation in the middle of a session, then mapping again: the session keeps
    // its 3 stored keyframes; a loop on a memory-only keyframe joins in memory, written nowhere.
    SessionManager m(o);
    ASSERT_EQ(m.view().restoredSessions(), 1);  // the localisation session was never stored
    addStraightSession(&m, 1, 3);
    EXPECT_TRUE(m.setLocalisation(true).ok());
    EXPECT_TRUE(m.setLocalisation(true).ok());  // again: said, nothing changes
    for (int k = 3; k < 5; ++k) ASSERT_TRUE(m.addKeyframe(keyframe(1, k, Pose2(k, 0, 0), Pose2(k - 1, 0, 0))).ok());
    EXPECT_TRUE(m.setLocalisation(false).ok());
    for (int k = 5; k < 7; ++k) ASSERT_TRUE(m.addKeyframe(keyframe(1, k, Pose2(k, 0, 0), Pose2(k - 1, 0, 0))).ok());
    ASSERT_TRUE(m.addLoop(globalLoop(0, 2, 1, 5, Pose2(-3, 1, 0))).ok());
    EXPECT_EQ(m.view().mapOf(1), 0);  // mapping again: the automatic join happens
    ASSERT_TRUE(m.endSession(30.0).ok());
    EXPECT_EQ(m.view().stats().store_failures, 0);
  }
  {
    SessionManager again(o);
    ASSERT_EQ(again.view().restoredSessions(), 2);
    EXPECT_EQ(again.view().list()[0].keyframes, 8);
    EXPECT_EQ(again.view().list()[1].keyframes, 3);
    EXPECT_TRUE(again.view().loops().empty());  // the only loop was on a memory-only keyframe
    // A session cut by the mode that also ends in it: its end is not written (the store keeps it
    // as recording, like an interrupted run).
    addStraightSession(&again, 2, 3);
    EXPECT_TRUE(again.setLocalisation(true).ok());
    for (int k = 3; k < 5; ++k) ASSERT_TRUE(again.addKeyframe(keyframe(2, k, Pose2(k, 0, 0), Pose2(k - 1, 0, 0))).ok());
    ASSERT_TRUE(again.endSession(40.0).ok());
    EXPECT_EQ(again.view().stats().store_failures, 0);
  }
  // The next start restores its stored prefix all the same.
  SessionManager last(o);
  ASSERT_EQ(last.view().restoredSessions(), 3);
  EXPECT_EQ(last.view().list()[2].keyframes, 3);
  EXPECT_EQ(last.view().nextId(), 3);
}

TEST(SessionManager, TheAuditTrailRecordsJoinsSplitsLinksAndModeChangesWithCauseAndLoopsAndSurvivesARestart) {
  testing_util::ScopedTempDir dir("session_manager");
  const std::string db = (dir.path() / "s.db").string();
  SessionManagerOptions o = options(db);
  o.backend.join_min_loops = 5;  // the rule joins at the fifth loop
  o.requester = "service";
  std::vector<HistoryEntry> written;
  {
    SessionManager m(o);
    twoSessionsWithLoops(&m);
    ASSERT_EQ(m.view().mapOf(1), 0);
    ASSERT_TRUE(m.split(1).ok());
    Loop link = globalLoop(0, 6, 1, 6, Pose2(0, 1, 0));
    ASSERT_TRUE(m.addLink(link).ok());
    ASSERT_EQ(m.view().mapOf(1), 1);  // a split pair: the rule does not join it again by itself
    ASSERT_TRUE(m.join(0, 1, 1).ok());
    ASSERT_TRUE(m.setLocalisation(true).ok());
    ASSERT_TRUE(m.setLocalisation(false).ok());
    ASSERT_TRUE(m.split(1).ok());
    written = m.view().history();
  }
  ASSERT_EQ(written.size(), 6u);
  const std::vector<std::string> kinds{"join", "split", "link", "join", "mode", "split"};
  const std::vector<std::string> causes{"automatic", "service", "service", "service", "service", "service"};
  for (std::size_t i = 0; i < written.size(); ++i) {
    const HistoryEntry& e = written[i];
    EXPECT_EQ(e.id, static_cast<std::int64_t>(i + 1));
    EXPECT_EQ(e.kind, kinds[i]) << i;
    EXPECT_EQ(e.cause, causes[i]) << i;
    ASSERT_EQ(e.time_utc.size(), 20u) << e.time_utc;  // 2026-11-25T02:13:04Z
    EXPECT_EQ(e.time_utc[10], 'T');
    EXPECT_EQ(e.time_utc.back(), 'Z');
  }
  EXPECT_EQ(written[0].sessions, "0+1");
  EXPECT_EQ(written[0].loops, "0:1>1:1 0:2>1:2 0:3>1:3 0:4>1:4 0:5>1:5");
  EXPECT_NE(written[0].message.find("from 5 loops"), std::string::npos) << written[0].message;
  EXPECT_EQ(written[1].sessions, "1+0");
  EXPECT_EQ(written[1].loops, written[0].loops);  // released for a later join
  EXPECT_NE(written[1].message.find("undoes join #1"), std::string::npos) << written[1].message;
  EXPECT_EQ(written[2].sessions, "0,1");
  EXPECT_EQ(written[2].loops, "0:6>1:6");
  EXPECT_NE(written[2].message.find("global link 0:6>1:6: pose (0.0000 m, 1.0000 m, 0.0000 rad)"), std::string::npos)
      << written[2].message;
  EXPECT_NE(written[3].loops.find("0:6>1:6"), std::string::npos) << written[3].loops;
  EXPECT_NE(written[4].message.find("localisation mode from"), std::string::npos) << written[4].message;
  // The last change of the maps before it was join #4 (the mode entry in between does not count).
  EXPECT_NE(written[5].message.find("undoes join #4"), std::string::npos) << written[5].message;

  // In the store: a restart restores it, and the next entry follows on.
  SessionManager again(o);
  const std::vector<HistoryEntry>& h = again.view().history();
  ASSERT_EQ(h.size(), written.size());
  for (std::size_t i = 0; i < h.size(); ++i) {
    EXPECT_EQ(h[i].id, written[i].id);
    EXPECT_EQ(h[i].time_utc, written[i].time_utc);
    EXPECT_EQ(h[i].kind + h[i].cause + h[i].sessions + h[i].loops + h[i].message,
              written[i].kind + written[i].cause + written[i].sessions + written[i].loops + written[i].message);
  }
  ASSERT_TRUE(again.join(0, 1, 1).ok());
  EXPECT_EQ(again.view().history().back().id, 7);

  // offline_slam's manager (requester tool) without a store: the trail lives in memory.
  SessionManager tool(options());
  twoSessionsWithLoops(&tool);
  ASSERT_TRUE(tool.join(0, 1, 5).ok());
  ASSERT_EQ(tool.view().history().size(), 1u);
  EXPECT_EQ(tool.view().history()[0].cause, "tool");
  SessionManagerOptions bad = options();
  bad.requester = "operator";
  EXPECT_THROW(SessionManager{bad}, std::invalid_argument);
}

TEST(SessionManager, DeleteSessionRemovesASessionAloneInItsMapFromStoreAndMemoryOnlyWhenConfirmed) {
  testing_util::ScopedTempDir dir("session_manager");
  const std::string db = (dir.path() / "s.db").string();
  std::vector<Pose2> joined;
  {
    SessionManager m(options(db));
    twoSessionsWithLoops(&m);  // sessions 0 and 1, five global loops
    ASSERT_TRUE(m.join(0, 1, 5).ok());
    joined = m.view().poses(1);
    addStraightSession(&m, 2, 4);
    ASSERT_TRUE(m.addLoop(globalLoop(0, 6, 2, 1, Pose2(0, -1, 0))).ok());
    Loop own = globalLoop(2, 0, 2, 3, Pose2(3, 0, 0));
    own.kind = Loop::Kind::kLocal;
    ASSERT_TRUE(m.addLoop(own).ok());
    const std::vector<SessionSummary> before = m.view().list();
    auto unchanged = [&] {
      const std::vector<SessionSummary> now = m.view().list();
      ASSERT_EQ(now.size(), before.size());
      for (std::size_t i = 0; i < now.size(); ++i)
        EXPECT_EQ((std::vector<int>{now[i].id, now[i].map, now[i].keyframes, now[i].loops}),
                  (std::vector<int>{before[i].id, before[i].map, before[i].keyframes, before[i].loops}));
      EXPECT_EQ(m.view().loops().size(), 7u);
    };
    int id = -1;
    const Status recording = m.deleteSession("2", true, &id);
    EXPECT_EQ(recording.code, StatusCode::kFailedPrecondition);
    EXPECT_NE(recording.message.find("finish_session first"), std::string::npos) << recording.message;
    ASSERT_TRUE(m.endSession(30.0).ok());
    const Status shared = m.deleteSession("1", true);
    EXPECT_EQ(shared.code, StatusCode::kFailedPrecondition);
    EXPECT_NE(shared.message.find("split_session it off first"), std::string::npos) << shared.message;
    EXPECT_EQ(m.deleteSession("nope", true).code, StatusCode::kNotFound);
    const Status unconfirmed = m.deleteSession("session_2", false, &id);
    EXPECT_EQ(unconfirmed.code, StatusCode::kFailedPrecondition);
    EXPECT_NE(unconfirmed.message.find("(4 keyframes, 2 loops) from the store for good: call again with confirm true"),
              std::string::npos)
        << unconfirmed.message;
    EXPECT_EQ(id, 2);
    ASSERT_TRUE(m.setLocalisation(true).ok());
    EXPECT_EQ(m.deleteSession("2", true).code, StatusCode::kFailedPrecondition);
    ASSERT_TRUE(m.setLocalisation(false).ok());
    unchanged();

    ASSERT_TRUE(m.deleteSession("2", true, &id).ok());
    EXPECT_EQ(id, 2);
    EXPECT_FALSE(m.view().has(2));
    EXPECT_EQ(m.view().sessionIds(), (std::vector<int>{0, 1}));
    EXPECT_EQ(m.view().list()[0].loops, 5);  // the loop to session 2 went with it
    EXPECT_EQ(m.view().loops().size(), 5u);
    EXPECT_EQ(m.view().nextId(), 3);  // its id is not given again
    EXPECT_EQ(m.view().history().back().kind, "delete");
    EXPECT_EQ(m.view().history().back().sessions, "2");
    EXPECT_NE(m.view().history().back().message.find("'session_2' deleted (4 keyframes, 2 loops)"), std::string::npos)
        << m.view().history().back().message;
    for (std::size_t k = 0; k < joined.size(); ++k) EXPECT_NEAR(m.view().poses(1)[k].y(), joined[k].y(), 1e-9) << k;
    addStraightSession(&m, m.view().nextId(), 2);  // sessions go on after it
    EXPECT_EQ(m.view().activeSession(), 3);
    ASSERT_TRUE(m.endSession(40.0).ok());
    EXPECT_EQ(m.view().stats().store_failures, 0);
  }
  // The store: session 2 and its loops are gone; the joined map and session 3 (now 2) remain.
  SessionManager again(options(db));
  ASSERT_EQ(again.view().restoredSessions(), 3);
  EXPECT_EQ(again.view().list()[2].keyframes, 2);
  EXPECT_EQ(again.view().loops().size(), 5u);
  EXPECT_EQ(again.view().mapOf(1), 0);
  for (std::size_t k = 0; k < joined.size(); ++k) EXPECT_NEAR(again.view().poses(1)[k].y(), joined[k].y(), 1e-9) << k;
  ASSERT_GE(again.view().history().size(), 2u);
  EXPECT_EQ(again.view().history().back().kind, "delete");
  SessionManager none(options());
  addStraightSession(&none, 0, 2);
  EXPECT_EQ(none.deleteSession("0", true).code, StatusCode::kFailedPrecondition);  // no store
}

TEST(SessionManager, DeletingTheFirstSessionLeavesTheLaterOnesTheirPosesMapsLinksAndLoops) {
  // Session 0 alone (one loop to 1); 1 and 2 joined; 3 alone with three loops to 1. Deleting 0
  // moves every back-end index after it: nothing the others show may change, a later join works
  // and names the right sessions, and a restart gives the same maps under the same ids (1..3: a
  // session's id is its store id for life), and never gives id 0 again.
  testing_util::ScopedTempDir dir("session_manager");
  const std::string db = (dir.path() / "s.db").string();
  using Ends = std::tuple<int, int, int, int>;
  auto ends = [](const std::vector<Loop>& loops) {
    std::vector<Ends> out;
    for (const Loop& l : loops) out.emplace_back(l.session_a, l.keyframe_a, l.session_b, l.keyframe_b);
    return out;
  };
  std::vector<std::vector<Pose2>> poses;
  {
    SessionManager m(options(db));
    addStraightSession(&m, 0, 6);
    addStraightSession(&m, 1, 8);
    addStraightSession(&m, 2, 8);
    addStraightSession(&m, 3, 8);
    ASSERT_TRUE(m.endSession(50.0).ok());
    ASSERT_TRUE(m.addLoop(globalLoop(0, 2, 1, 2, Pose2(0, 1, 0))).ok());
    for (int k = 1; k <= 5; ++k) ASSERT_TRUE(m.addLoop(globalLoop(1, k, 2, k, Pose2(0, 1, 0))).ok());
    for (int k = 1; k <= 3; ++k) ASSERT_TRUE(m.addLoop(globalLoop(1, k, 3, k, Pose2(0, -1, 0))).ok());
    ASSERT_TRUE(m.join(1, 2, 5).ok());
    for (int s = 1; s <= 3; ++s) poses.push_back(m.view().poses(s));
    const std::vector<SessionLink> links = m.view().links();
    std::vector<Ends> kept;
    for (const Ends& e : ends(m.view().loops()))
      if (std::get<0>(e) != 0) kept.push_back(e);
    const int loops_of_1 = m.view().list()[1].loops;

    ASSERT_TRUE(m.deleteSession("0", true).ok());
    EXPECT_EQ(m.view().sessionIds(), (std::vector<int>{1, 2, 3}));
    for (int s = 1; s <= 3; ++s)
      for (std::size_t k = 0; k < poses[s - 1].size(); ++k)
        EXPECT_TRUE(approxEqual(m.view().poses(s)[k], poses[s - 1][k], 0.0, 0.0)) << s << " " << k;
    EXPECT_EQ((std::vector<int>{m.view().mapOf(1), m.view().mapOf(2), m.view().mapOf(3)}), (std::vector<int>{1, 1, 3}));
    ASSERT_EQ(m.view().links().size(), links.size());
    for (std::size_t i = 0; i < links.size(); ++i)
      EXPECT_EQ((std::vector<int>{m.view().links()[i].map, m.view().links()[i].previous, m.view().links()[i].current,
                                  m.view().links()[i].loops}),
                (std::vector<int>{links[i].map, links[i].previous, links[i].current, links[i].loops}));
    EXPECT_EQ(ends(m.view().loops()), kept);
    EXPECT_EQ(m.view().list()[0].loops, loops_of_1 - 1);  // list()[0] is session 1 now
    EXPECT_EQ(m.addLoop(globalLoop(0, 1, 1, 1, Pose2(0, 1, 0))).code, StatusCode::kNotFound);  // deleted: no wait
    ASSERT_TRUE(m.join(1, 3, 3).ok());
    EXPECT_EQ(m.view().history().back().kind, "join");
    EXPECT_EQ(m.view().history().back().sessions, "1,2+3");
    EXPECT_EQ(m.view().history().back().loops, "1:1>3:1 1:2>3:2 1:3>3:3");
    for (int s = 1; s <= 3; ++s) poses[s - 1] = m.view().poses(s);
    EXPECT_EQ(m.view().stats().store_failures, 0);
  }
  SessionManager again(options(db));
  ASSERT_EQ(again.view().restoredSessions(), 3);
  EXPECT_EQ(again.view().sessionIds(), (std::vector<int>{1, 2, 3}));
  EXPECT_EQ((std::vector<int>{again.view().mapOf(1), again.view().mapOf(2), again.view().mapOf(3)}),
            (std::vector<int>{1, 1, 1}));
  EXPECT_EQ(again.view().loops().size(), 8u);
  for (int s = 1; s <= 3; ++s)
    for (std::size_t k = 0; k < poses[s - 1].size(); ++k)
      EXPECT_TRUE(approxEqual(again.view().poses(s)[k], poses[s - 1][k], 1e-9, 1e-9)) << s << " " << k;
  EXPECT_EQ(again.view().nextId(), 4);
}

// A session's id is its store id for life. Run 1 records sessions 0..3 and deletes 0 and 1; after
// a restart 2 and 3 keep their ids and names (they used to come back as 0 and 1, ids that had
// belonged to other sessions), a new session takes 4, past every stored or deleted id, and its
// store row is 4; after a second restart all three keep id and name, and the next id is 5.
TEST(SessionManager, ASessionKeepsItsIdAndNameThroughRestartsAndIdsAreNeverGivenTwice) {
  testing_util::ScopedTempDir dir("session_manager");
  const std::string db = (dir.path() / "s.db").string();
  using Named = std::vector<std::pair<int, std::string>>;
  auto named = [](const SessionManager& m) {
    Named out;
    for (const SessionSummary& s : m.view().list()) out.emplace_back(s.id, s.name);
    return out;
  };
  auto storeRows = [&db]() {
    Named out;
    SessionStore store(db, StoreAccess::kReadOnly);
    for (const StoredSession& s : store.sessions()) out.emplace_back(static_cast<int>(s.id), s.name);
    return out;
  };
  {
    SessionManager m(options(db));
    for (int s = 0; s < 4; ++s) addStraightSession(&m, s, 4);
    ASSERT_TRUE(m.endSession(60.0).ok());
    ASSERT_TRUE(m.deleteSession("0", true).ok());
    ASSERT_TRUE(m.deleteSession("session_1", true).ok());
  }
  {
    SessionManager m(options(db));
    EXPECT_EQ(named(m), (Named{{2, "session_2"}, {3, "session_3"}}));
    EXPECT_EQ(m.view().findSession("3"), 3);
    EXPECT_EQ(m.view().findSession("0"), -1);  // a deleted id names nothing
    EXPECT_EQ(m.view().nextId(), 4);
    EXPECT_EQ(m.view().firstNewId(), 4);
    EXPECT_TRUE(m.view().restored(3));
    EXPECT_EQ(m.view().mapOf(3), 3);  // a map is named by its first session's id: the store's
    int started = -1;
    ASSERT_TRUE(m.startSession("", 70.0, -1, &started).ok());
    EXPECT_EQ(started, 4);
    addStraightSession(&m, 4, 3);
    EXPECT_FALSE(m.view().restored(4));
    EXPECT_EQ(m.startSession("", 80.0, 1).code, StatusCode::kInvalidArgument);  // a deleted id: not new
    ASSERT_TRUE(m.endSession(80.0).ok());
  }
  {
    SessionManager m(options(db));
    EXPECT_EQ(named(m), (Named{{2, "session_2"}, {3, "session_3"}, {4, "session_4"}}));
    EXPECT_EQ(m.view().nextId(), 5);
    EXPECT_EQ(m.view().list().back().keyframes, 3);
  }
  EXPECT_EQ(storeRows(), (Named{{2, "session_2"}, {3, "session_3"}, {4, "session_4"}}));
}

TEST(SessionManager, ASplitAfterARestartDoesNotClaimToUndoAnEarlierRunsJoinOfOtherSessions) {
  // Run 1 joins 4+5, then 2+3, then deletes 0 and 1. Stores written before session ids were store
  // ids numbered the sessions 0..k-1 at each restart (the old 4 and 5 became 2 and 3), so an
  // earlier run's "2+3" may have joined other sessions: a split after a restart never claims to
  // undo an earlier run's join (the ids stay now; the rule stays for such stores).
  testing_util::ScopedTempDir dir("session_manager");
  const std::string db = (dir.path() / "s.db").string();
  {
    SessionManager m(options(db));
    for (int s = 0; s < 6; ++s) addStraightSession(&m, s, 4);
    ASSERT_TRUE(m.endSession(60.0).ok());
    for (int s : {4, 2}) {
      ASSERT_TRUE(m.addLoop(globalLoop(s, 1, s + 1, 1, Pose2(0, 1, 0))).ok());
      ASSERT_TRUE(m.join(s, s + 1, 1).ok());
    }
    ASSERT_TRUE(m.deleteSession("0", true).ok());
    ASSERT_TRUE(m.deleteSession("1", true).ok());
    ASSERT_EQ(m.view().history().size(), 4u);
    EXPECT_EQ(m.view().history()[1].sessions, "2+3");
  }
  SessionManager again(options(db));
  ASSERT_EQ(again.view().restoredSessions(), 4);
  ASSERT_EQ(again.view().mapOf(3), 2);
  ASSERT_TRUE(again.split(3).ok());
  EXPECT_EQ(again.view().history().back().sessions, "3+2");
  EXPECT_EQ(again.view().history().back().message.find("undoes"), std::string::npos)
      << again.view().history().back().message;
  ASSERT_TRUE(again.join(2, 3, 1).ok());  // this run's join: its split is an undo again
  ASSERT_TRUE(again.split(3).ok());
  EXPECT_NE(again.view().history().back().message.find("undoes join #6"), std::string::npos)
      << again.view().history().back().message;
}

TEST(SessionManager, ANewSessionRelocalisesInAStoredMapOnlyAndWithItsOdometryCorrection) {
  // Session 0 stored; after a restart session 1 (1 m beside it) relocalises in map 0 from two
  // consistent loops, in localisation mode (nothing joined). Session 2, recorded in this run, is no
  // relocalisation target: this run's maps join as usual.
  testing_util::ScopedTempDir dir("session_manager");
  const std::string db = (dir.path() / "s.db").string();
  SessionManagerOptions o = options(db);
  o.backend.join_min_inliers = 60;
  {
    SessionManager m(o);
    addStraightSession(&m, 0, 8);
    ASSERT_TRUE(m.endSession(8.0).ok());
  }
  SessionManager m(o);
  ASSERT_TRUE(m.setLocalisation(true).ok());
  addStraightSession(&m, 1, 4);
  EXPECT_FALSE(m.view().relocalise(1));
  ASSERT_TRUE(m.addLoop(globalLoop(0, 2, 1, 2, Pose2(0, 1, 0))).ok());
  EXPECT_FALSE(m.view().relocalise(1)) << "one loop";
  ASSERT_TRUE(m.addLoop(globalLoop(0, 3, 1, 3, Pose2(0, 1, 0))).ok());
  const auto r = m.view().relocalise(1);
  ASSERT_TRUE(r);
  EXPECT_EQ(r->map, 0);
  EXPECT_EQ(r->loops, 2);
  EXPECT_EQ(r->keyframe, 3);
  EXPECT_TRUE(approxEqual(r->pose.mean, Pose2(3, 1, 0), 1e-6, 1e-6)) << r->pose.mean;  // a (+) z: (3, 0) (+) (0, 1)
  // The correction takes the session's odometry frame into map 0: its last odometry pose lands there.
  EXPECT_TRUE(approxEqual(compose(r->correction, m.view().odometryPoses(1).back()), r->pose.mean, 1e-6, 1e-6));
  EXPECT_EQ(m.view().mapIds(), (std::vector<int>{0, 1}));
  addStraightSession(&m, 2, 4);
  ASSERT_TRUE(m.addLoop(globalLoop(1, 1, 2, 1, Pose2(0, 1, 0))).ok());
  ASSERT_TRUE(m.addLoop(globalLoop(1, 2, 2, 2, Pose2(0, 1, 0))).ok());
  EXPECT_FALSE(m.view().relocalise(2)) << "session 1's map holds no stored session";
  EXPECT_FALSE(m.view().relocalise(7)) << "no such session";
}

// The hash exchange: another vehicle's session (from its hashes) grows beside this vehicle's
// recording session; the loops between them join the two maps once one of them has ended, as
// one vehicle's two sessions joined by the same loops.
TEST(SessionManager, AnotherVehiclesSessionGrowsBesideTheActiveOneAndJoinsOnceOneEnds) {
  testing_util::ScopedTempDir dir("session_manager");
  const std::string db = (dir.path() / "s.db").string();
  SessionManagerOptions o = options(db);
  o.backend.join_min_loops = 3;  // automatic joins by 3 loops
  std::vector<SessionEvent> events;
  {
    SessionManager m(o, [&](const SessionEvent& e) { events.push_back(e); });
    // Interleaved as they arrive live: our keyframe k, then the other vehicle's keyframe k (its
    // own session 7 there), one metre to our left; from k = 1 a loop between them.
    for (int k = 0; k < 8; ++k) {
      const Pose2 pose(k, 0, 0), previous(std::max(0, k - 1), 0, 0);
      ASSERT_TRUE(m.addKeyframe(keyframe(0, k, pose, previous)).ok());
      KeyframeInput theirs = keyframe(7, k, pose, previous);
      theirs.features.descriptors = cv::Mat::ones(3, 128, CV_8U);  // not kept: only what crossed the link
      int local = -1;
      const Status st = m.fleet().addKeyframe("auv_b", theirs, &local);
      ASSERT_TRUE(st.ok()) << st.message;
      ASSERT_EQ(local, 1);
      if (k >= 1 && k <= 5) {
        ASSERT_TRUE(m.addLoop(globalLoop(1, k, 0, k, Pose2(0, -1, 0))).ok());
      }
    }
    EXPECT_EQ(m.view().activeSession(), 0);
    EXPECT_EQ(m.view().foreignSession("auv_b", 7), 1);
    EXPECT_EQ(m.view().vehicleOf(1), "auv_b");
    EXPECT_EQ(m.view().name(1), "auv_b_session_7");
    // Both recording, each in its own map: five loops wait, no join yet.
    EXPECT_NE(m.view().mapOf(0), m.view().mapOf(1));
    const std::vector<SessionSummary> l = m.view().list();
    ASSERT_EQ(l.size(), 2u);
    EXPECT_EQ(l[0].state, SessionState::kActive);
    EXPECT_EQ(l[1].state, SessionState::kActive);
    EXPECT_EQ(l[1].vehicle, "auv_b");
    EXPECT_EQ(l[1].keyframes, 8);

    // Misuse changes nothing.
    EXPECT_EQ(m.fleet().addKeyframe("", keyframe(7, 8, Pose2(8, 0, 0), Pose2(7, 0, 0))).code,
              StatusCode::kInvalidArgument);
    EXPECT_EQ(m.fleet().addKeyframe("auv b/../x", keyframe(7, 8, Pose2(8, 0, 0), Pose2(7, 0, 0))).code,
              StatusCode::kInvalidArgument);
    EXPECT_EQ(m.fleet().addKeyframe("auv_b", keyframe(7, 3, Pose2(3, 0, 0), Pose2(2, 0, 0))).code,
              StatusCode::kFailedPrecondition);  // stale
    EXPECT_EQ(m.addKeyframe(keyframe(1, 8, Pose2(8, 0, 0), Pose2(7, 0, 0))).code,
              StatusCode::kFailedPrecondition);  // our odometry cannot write into their session
    EXPECT_EQ(m.fleet().endSession("auv_c", 7, 9.0).code, StatusCode::kNotFound);
    EXPECT_EQ(m.view().sessionIds(), (std::vector<int>{0, 1}));
    EXPECT_EQ(m.view().list()[1].keyframes, 8);

    // Their session ends: the postponed join is made; ours goes on recording at the map's end.
    ASSERT_TRUE(m.fleet().endSession("auv_b", 7, 107.5).ok());
    EXPECT_EQ(m.view().mapOf(0), m.view().mapOf(1));
    EXPECT_EQ(m.view().mapOf(0), 1);  // the finished session first: the map is named by it
    EXPECT_EQ(m.view().foreignSession("auv_b", 7), -1);
    EXPECT_EQ(m.fleet().addKeyframe("auv_b", keyframe(7, 8, Pose2(8, 0, 0), Pose2(7, 0, 0))).code,
              StatusCode::kFailedPrecondition);  // ended
    ASSERT_TRUE(m.addKeyframe(keyframe(0, 8, Pose2(8, 0, 0), Pose2(7, 0, 0))).ok());
    const std::vector<Pose2> ours = m.view().poses(0), theirs = m.view().poses(1);
    ASSERT_EQ(ours.size(), 9u);
    for (int k = 0; k < 8; ++k) {
      EXPECT_NEAR(ours[k].x(), theirs[k].x(), 1e-6) << k;
      EXPECT_NEAR(ours[k].y(), theirs[k].y() - 1.0, 1e-6) << k;
    }
    EXPECT_NEAR(ours[8].x(), theirs[7].x() + 1.0, 1e-6);
    int joins = 0;
    for (const SessionEvent& e : events) joins += e.kind == SessionEvent::Kind::kMapsJoined;
    EXPECT_EQ(joins, 1);

    // Its origin sent again: stale. Another keyframe 0 of its session 7 (it restarted on a new
    // store): a new session, named apart; left recording when the manager goes.
    EXPECT_EQ(m.fleet().addKeyframe("auv_b", keyframe(7, 0, Pose2(), Pose2())).code, StatusCode::kFailedPrecondition);
    KeyframeInput restarted = keyframe(7, 0, Pose2(), Pose2());
    restarted.stamp_s = 500.0;
    int local = -1;
    ASSERT_TRUE(m.fleet().addKeyframe("auv_b", restarted, &local).ok());
    EXPECT_EQ(local, 2);
    EXPECT_EQ(m.view().name(2), "auv_b_session_7_2");
    EXPECT_EQ(m.view().foreignSession("auv_b", 7), 2);
    EXPECT_EQ(m.view().mapOf(2), 2);  // a map of its own
    EXPECT_EQ(m.view().stats().store_failures, 0);
  }
  // In the store: their session (hashes and motions, no features), where it came from, the join.
  SessionManager again(options(db));
  ASSERT_EQ(again.view().restoredSessions(), 3);
  EXPECT_EQ(again.view().name(1), "auv_b_session_7");
  EXPECT_EQ(again.view().vehicleOf(1), "auv_b");  // whose it is, and its id there, from the provenance
  EXPECT_EQ(again.view().remoteIdOf(1), 7);
  EXPECT_EQ(again.view().vehicleOf(0), "");
  EXPECT_EQ(again.view().list()[1].vehicle, "auv_b");
  EXPECT_EQ(again.view().list()[1].state, SessionState::kUnloaded);
  EXPECT_EQ(again.view().foreignSession("auv_b", 7), -1);  // not recording here any more
  EXPECT_EQ(again.view().poses(1).size(), 8u);
  EXPECT_EQ(again.view().mapOf(0), again.view().mapOf(1));
  EXPECT_EQ(again.view().loops().size(), 5u);
  EXPECT_TRUE(again.view().storedFeatures(1, 3).points.empty());
  SessionStore store(db, StoreAccess::kReadOnly);
  const std::vector<SessionProvenance> p = store.provenance();
  ASSERT_EQ(p.size(), 2u);
  EXPECT_EQ(p[0].vehicle, "auv_b");
  EXPECT_EQ(p[0].source_session, 7);
  EXPECT_EQ(p[0].source_file, "fleet:auv_b");
  // The other vehicle's sessions finished in the store, the one left recording by the destructor
  // too (ours, still recording, stays so: an interrupted run's, as always).
  for (const StoredSession& st : store.sessions())
    EXPECT_EQ(st.state, st.name.rfind("auv_b", 0) == 0 ? StoredSessionState::kFinished : StoredSessionState::kRecording)
        << st.name;
  EXPECT_EQ(again.view().name(2), "auv_b_session_7_2");
  EXPECT_EQ(again.view().vehicleOf(2), "auv_b");
}

TEST(SessionManager, TheStoresDirectoryItCreatesIsTheOwnersOnly) {
  testing_util::ScopedTempDir dir("session_manager");
  const std::filesystem::path store_dir = dir.path() / "missions";
  { SessionManager m(options((store_dir / "s.db").string())); }
  const auto perms = std::filesystem::status(store_dir).permissions();
  EXPECT_EQ(perms & std::filesystem::perms::all, std::filesystem::perms::owner_all);
}

TEST(SessionManager, SessionIdsBeyondTheMaximumAreRefusedAndIdsNeverWrap) {
  SessionManager m(options());
  addStraightSession(&m, 0, 2);
  // A corrupt message naming session 2^31 - 1: it used to open that session, and
  // the next start_session wrapped to -2^31 and every later one failed.
  for (int id : {INT_MAX, kMaxSessionId + 1}) {
    const Status st = m.addKeyframe(keyframe(id, 0, Pose2(), Pose2()));
    EXPECT_EQ(st.code, StatusCode::kInvalidArgument) << id;
    EXPECT_NE(st.message.find(std::to_string(kMaxSessionId)), std::string::npos) << st.message;
    EXPECT_FALSE(m.view().has(id));
  }
  EXPECT_EQ(m.view().stats().keyframes_refused, 2);
  EXPECT_EQ(m.view().nextId(), 1);
  EXPECT_EQ(m.view().activeSession(), 0);
  // A loop naming such a session is refused at once: it does not wait for a keyframe that may
  // never come.
  bool waiting = true;
  EXPECT_EQ(m.addLoop(globalLoop(0, 1, INT_MAX, 0, Pose2()), &waiting).code, StatusCode::kInvalidArgument);
  EXPECT_FALSE(waiting);
  EXPECT_EQ(m.addLoop(globalLoop(-1, 0, 0, 1, Pose2()), &waiting).code, StatusCode::kInvalidArgument);
  EXPECT_FALSE(waiting);
  int id = -1;
  ASSERT_TRUE(m.startSession("next", 5.0, -1, &id).ok());
  EXPECT_EQ(id, 1);
  EXPECT_EQ(m.startSession("too far", 6.0, INT_MAX).code, StatusCode::kInvalidArgument);
  // The largest id is still usable (given explicitly); past it start_session answers, and
  // nothing wraps.
  ASSERT_TRUE(m.startSession("the last id", 6.5, kMaxSessionId).ok());
  addStraightSession(&m, kMaxSessionId, 2);
  EXPECT_EQ(m.view().activeSession(), kMaxSessionId);
  const Status full = m.startSession("past the last id", 7.0);
  EXPECT_EQ(full.code, StatusCode::kResourceExhausted) << full.message;
  EXPECT_EQ(m.view().activeSession(), kMaxSessionId);
  for (int s : m.view().sessionIds()) EXPECT_GE(s, 0);
}

TEST(SessionManager, StartSessionIsRefusedWhileTooManySessionsInARowHaveNoKeyframe) {
  SessionManagerOptions o = options();
  o.max_empty_sessions = 2;
  SessionManager m(o);
  addStraightSession(&m, 0, 2);
  ASSERT_TRUE(m.startSession("a", 3.0).ok());
  ASSERT_TRUE(m.startSession("b", 4.0).ok());
  // Sessions 1 and 2 have no keyframe: a third empty one is refused, with a reason.
  const Status st = m.startSession("c", 5.0);
  EXPECT_EQ(st.code, StatusCode::kResourceExhausted) << st.message;
  EXPECT_NE(st.message.find("max_empty_sessions"), std::string::npos) << st.message;
  EXPECT_EQ(m.view().sessionIds(), (std::vector<int>{0, 1, 2}));
  EXPECT_EQ(m.view().activeSession(), 2);
  EXPECT_FALSE(m.view().hasKeyframe(2));
  EXPECT_TRUE(m.view().hasKeyframe(0));
  // The session's first keyframe lifts the limit.
  addStraightSession(&m, 2, 1);
  EXPECT_TRUE(m.view().hasKeyframe(2));
  EXPECT_TRUE(m.startSession("c", 5.0).ok());
  // 3,000 calls leave at most max_empty_sessions empty sessions.
  for (int i = 0; i < 3000; ++i) m.startSession("x" + std::to_string(i), 6.0 + i);
  EXPECT_EQ(m.view().sessionIds().size(), 5u);
  // A name past kMaxSessionNameLength is refused and changes nothing (a 100 kB name was stored before).
  const std::vector<int> ids = m.view().sessionIds();
  EXPECT_EQ(m.startSession(std::string(100000, 'n'), 9000.0).code, StatusCode::kInvalidArgument);
  EXPECT_EQ(m.view().sessionIds(), ids);
  SessionManagerOptions bad = options();
  bad.max_empty_sessions = -1;  // 0 is no limit (offline_slam)
  EXPECT_THROW(SessionManager{bad}, std::invalid_argument);
}

TEST(SessionManager, RepliesNameTheStoreByItsFileNameOnly) {
  testing_util::ScopedTempDir dir("session_manager");
  const std::string db = (dir.path() / "private_missions" / "s.db").string();
  { SessionManager m(options(db)); }
  SessionManager again(options(db));
  ReloadedSession r;
  const Status st = again.reload("nope", &r);
  EXPECT_EQ(st.code, StatusCode::kNotFound);
  EXPECT_NE(st.message.find("s.db"), std::string::npos) << st.message;
  EXPECT_EQ(st.message.find("private_missions"), std::string::npos) << st.message;
  EXPECT_EQ(st.message.find(dir.path().string()), std::string::npos) << st.message;
}

TEST(SessionManager, BadOptionsAndABadStoreAreRefusedAtConstruction) {
  SessionManagerOptions bad = options();
  bad.max_keyframe_gap = -1;
  EXPECT_THROW(SessionManager{bad}, std::invalid_argument);
  testing_util::ScopedTempDir dir("session_manager");
  const std::filesystem::path junk = dir.path() / "junk.db";
  {
    std::ofstream out(junk);
    out << std::string(4096, 'x');
  }
  EXPECT_THROW(SessionManager{options(junk.string())}, StoreError);
  EXPECT_EQ(std::filesystem::file_size(junk), 4096u);  // left untouched
}

TEST(SessionManager, AGatedLoopIsMarkedRefusedAndWrittenApartFromTheAcceptedOnes) {
  // A straight session of 8 keyframes 1 m apart: a local loop that agrees, and one 3 m off.
  SessionManager m(options());
  addStraightSession(&m, 0, 8);
  Loop good = globalLoop(0, 1, 0, 6, Pose2(5.0, 0.0, 0.0));
  good.kind = Loop::Kind::kLocal;
  Loop wrong = globalLoop(0, 2, 0, 7, Pose2(5.0, 3.0, 0.0));
  wrong.kind = Loop::Kind::kLocal;
  ASSERT_TRUE(m.addLoop(good).ok());
  ASSERT_TRUE(m.addLoop(wrong).ok());  // received; the back-end refuses it
  ASSERT_EQ(m.view().loops().size(), 2u);
  EXPECT_FALSE(m.view().loopRefused(0));
  EXPECT_TRUE(m.view().loopRefused(1));
  EXPECT_FALSE(m.view().loopRefused(5));  // no such loop
  EXPECT_EQ(m.view().backendStats().loops_gated, 1);
  testing_util::ScopedTempDir dir("run_outputs");
  writeRunOutputs(dir.path().string(), m.view(), {}, 1, StageTimes());
  auto lines = [&](const char* name) {
    std::ifstream f(dir.path() / name);
    std::vector<std::string> out;
    for (std::string line; std::getline(f, line);) out.push_back(line);
    return out;
  };
  EXPECT_EQ(lines("loops.csv"),
            (std::vector<std::string>{"session_a,index_a,session_b,index_b,kind,inliers", "0,10,0,60,local,50"}));
  EXPECT_EQ(lines("loops_refused.csv"),
            (std::vector<std::string>{"session_a,index_a,session_b,index_b,kind,inliers", "0,20,0,70,local,50"}));
}

// A store that cannot grow (store_max_mb just above the file's size: a full disk): each write
// that does not fit is counted (store_failures) and logged, the manager goes on in memory (keyframes,
// loops, a join answered OK), and the store stays restorable: a session's stored keyframes stay a
// prefix (a big keyframe that fails is not followed by a small one that would fit: a gap would make
// the store unrestorable), and no loop is stored on a keyframe the store lacks.
TEST(SessionManager, AFullStoreIsCountedAndTheManagerGoesOnWithARestorableStore) {
  testing_util::ScopedTempDir dir("session_manager");
  const std::string db = (dir.path() / "s.db").string();
  {
    SessionManager m(options(db));
    addStraightSession(&m, 0, 4);
    ASSERT_TRUE(m.endSession(4.0).ok());
  }
  SessionManagerOptions o = options(db);
  // Room for small writes (64 kB more than the file holds), none for a 390 kB keyframe.
  o.store_max_mb = static_cast<double>(std::filesystem::file_size(db) + 65536) / 1048576.0;
  {
    std::vector<std::string> log;
    SessionManager m(o, {}, [&](const std::string& line) { log.push_back(line); });
    ASSERT_EQ(m.view().restoredSessions(), 1);
    for (int k = 0; k < 8; ++k) {
      KeyframeInput in = keyframe(1, k, Pose2(k, 0, 0), Pose2(std::max(0, k - 1), 0, 0));
      if (k % 2 == 0) {  // big ones (3000 features, 390 kB) between small ones (no features)
        in.features.image_size = cv::Size(640, 480);
        for (int i = 0; i < 3000; ++i) in.features.keypoints.emplace_back(cv::Point2f(i % 640, i / 640), 1.0f);
        in.features.descriptors = cv::Mat(3000, 128, CV_8U, cv::Scalar(7));
      }
      ASSERT_TRUE(m.addKeyframe(in).ok());  // the manager goes on
    }
    for (int k = 1; k <= 3; ++k) ASSERT_TRUE(m.addLoop(globalLoop(0, k, 1, k, Pose2(0, 1, 0))).ok());
    ASSERT_TRUE(m.join(0, 1, 3).ok());
    EXPECT_EQ(m.view().mapOf(1), 0);  // joined in memory
    EXPECT_GT(m.view().stats().store_failures, 0);
    bool full = false;
    for (const std::string& line : log) full = full || line.find("the disk is full") != std::string::npos;
    EXPECT_TRUE(full) << "no store failure logged";
    const long failures = m.view().stats().store_failures;
    ASSERT_TRUE(m.endSession(9.0).ok());
    EXPECT_GE(m.view().stats().store_failures, failures);
  }
  // What the store kept restores: session 1's keyframes are a prefix, every stored loop on
  // stored keyframes.
  SessionManager again(options(db));
  const std::vector<SessionSummary> list = again.view().list();
  ASSERT_GE(list.size(), 1u);
  EXPECT_EQ(list[0].keyframes, 4);
  if (list.size() > 1) {
    EXPECT_LT(list[1].keyframes, 8);
  }
  EXPECT_EQ(again.view().stats().store_failures, 0);
}

// A session's id is the back-end's to give. A keyframe naming a session it did not open (past
// nextId()) is refused, counted and held, ends nothing and spends no id (one such message used to
// open session 999999, every real keyframe after it stale, and the next session after a restart
// 1,000,000). The legitimate ways in still work: the odometry's next session (after a tracking
// loss it takes max(session + 1, next_free), the next id), start_session, a restart, and a
// session whose predecessors were lost on the way (the next keyframe continues the held one).
TEST(SessionManager, AKeyframeOfASessionNotOpenedIsRefusedEndsNothingAndSpendsNoId) {
  testing_util::ScopedTempDir dir("session_manager");
  const std::string db = (dir.path() / "s.db").string();
  {
    SessionManager m(options(db));
    const Status first = m.addKeyframe(keyframe(999999, 0, Pose2(), Pose2()));
    EXPECT_EQ(first.code, StatusCode::kFailedPrecondition);
    EXPECT_NE(first.message.find("session 999999"), std::string::npos) << first.message;
    EXPECT_FALSE(m.view().has(999999));
    addStraightSession(&m, 0, 3);  // 0:0 does not continue the held keyframe: it is dropped
    for (int stray : {500000, 2, kMaxSessionId}) {
      const Status st = m.addKeyframe(keyframe(stray, 0, Pose2(), Pose2()));
      EXPECT_EQ(st.code, StatusCode::kFailedPrecondition) << stray;
      EXPECT_NE(st.message.find("the next is 1"), std::string::npos) << st.message;
    }
    ASSERT_TRUE(m.addKeyframe(keyframe(0, 3, Pose2(3, 0, 0), Pose2(2, 0, 0))).ok());  // session 0 goes on
    EXPECT_EQ(m.view().activeSession(), 0);
    EXPECT_EQ(m.view().sessionIds(), (std::vector<int>{0}));
    EXPECT_EQ(m.view().nextId(), 1);
    EXPECT_EQ(m.view().stats().keyframes_unopened, 4);
    // The odometry's next session (a tracking loss): the next id.
    addStraightSession(&m, 1, 2);
    // Its session 2 lost on the way, every keyframe: session 3's first keyframe is held, its next
    // one continues it, and session 3 opens with both (id 2 never given).
    EXPECT_EQ(m.addKeyframe(keyframe(3, 0, Pose2(), Pose2())).code, StatusCode::kFailedPrecondition);
    ASSERT_TRUE(m.addKeyframe(keyframe(3, 1, Pose2(1, 0, 0), Pose2())).ok());
    EXPECT_EQ(m.view().sessionIds(), (std::vector<int>{0, 1, 3}));
    EXPECT_EQ(m.view().list().back().keyframes, 2);
    EXPECT_EQ(m.view().stats().keyframe_jumps, 0);
    addStraightSession(&m, 4, 1);  // and the one after it: the next id again
    // Two messages far past the next id that continue each other open a session under the next
    // id (dense), their ids mapped onto it.
    EXPECT_EQ(m.addKeyframe(keyframe(999999, 0, Pose2(), Pose2())).code, StatusCode::kFailedPrecondition);
    ASSERT_TRUE(m.addKeyframe(keyframe(999999, 1, Pose2(1, 0, 0), Pose2())).ok());
    ASSERT_TRUE(m.addKeyframe(keyframe(999999, 2, Pose2(2, 0, 0), Pose2(1, 0, 0))).ok());
    EXPECT_EQ(m.view().sessionIds(), (std::vector<int>{0, 1, 3, 4, 5}));
    EXPECT_EQ(m.view().list().back().keyframes, 3);
    EXPECT_EQ(m.view().nextId(), 6);
    int started = -1;
    ASSERT_TRUE(m.startSession("dive", 50.0, -1, &started).ok());
    EXPECT_EQ(started, 6);
    addStraightSession(&m, 6, 2);
  }
  // A restart keeps the ids, and the next is past them: 7, not 1,000,000.
  SessionManager again(options(db));
  EXPECT_EQ(again.view().sessionIds(), (std::vector<int>{0, 1, 3, 4, 5, 6}));
  EXPECT_EQ(again.view().nextId(), 7);
  EXPECT_EQ(again.addKeyframe(keyframe(6, 2, Pose2(2, 0, 0), Pose2(1, 0, 0))).code,
            StatusCode::kFailedPrecondition);  // stored: stale
  EXPECT_EQ(again.addKeyframe(keyframe(999999, 0, Pose2(), Pose2())).code, StatusCode::kFailedPrecondition);
  addStraightSession(&again, 7, 2);
  EXPECT_EQ(again.view().nextId(), 8);
}

// Another vehicle's session takes the next id: active_session tells our odometry the next free
// one, and our next session, at that id, goes in. When our odometry took the id in the same
// instant (before it was told), its first keyframe is held and the next one continues it: our
// session goes in under the next free id, while a loop detector's loop naming that id is the
// other vehicle's session's. A lone keyframe naming their session changes nothing.
TEST(SessionManager, OurSessionAfterAnotherVehiclesGoesInWhicheverTookTheIdFirst) {
  SessionManager m(options());
  addStraightSession(&m, 0, 3);
  int local = -1;
  ASSERT_TRUE(m.fleet().addKeyframe("auv_b", keyframe(0, 0, Pose2(), Pose2()), &local).ok());
  ASSERT_EQ(local, 1);
  EXPECT_EQ(m.view().nextId(), 2);
  addStraightSession(&m, 2, 2);  // told next_session 2: max(0 + 1, 2)
  EXPECT_EQ(m.view().activeSession(), 2);
  ASSERT_TRUE(m.fleet().addKeyframe("auv_b", keyframe(1, 0, Pose2(), Pose2()), &local).ok());
  ASSERT_EQ(local, 3);
  // A lone keyframe of ours naming 3: refused, held, dropped by the next one; session 2 goes on.
  EXPECT_EQ(m.addKeyframe(keyframe(3, 5, Pose2(), Pose2())).code, StatusCode::kFailedPrecondition);
  ASSERT_TRUE(m.addKeyframe(keyframe(2, 2, Pose2(2, 0, 0), Pose2(1, 0, 0))).ok());
  EXPECT_EQ(m.view().activeSession(), 2);
  // Our odometry's session 3, started as the other vehicle's took 3: it becomes session 4.
  EXPECT_EQ(m.addKeyframe(keyframe(3, 0, Pose2(), Pose2())).code, StatusCode::kFailedPrecondition);
  ASSERT_TRUE(m.addKeyframe(keyframe(3, 1, Pose2(1, 0, 0), Pose2())).ok());
  ASSERT_TRUE(m.addKeyframe(keyframe(3, 2, Pose2(2, 0, 0), Pose2(1, 0, 0))).ok());
  EXPECT_EQ(m.view().activeSession(), 4);
  EXPECT_EQ(m.view().vehicleOf(4), "");
  EXPECT_EQ(m.view().stamps(4).size(), 3u);
  EXPECT_EQ(m.view().vehicleOf(3), "auv_b");
  EXPECT_EQ(m.view().stamps(3).size(), 1u);
  // A loop detector's loop naming 3 is the other vehicle's session.
  ASSERT_TRUE(m.addLoop(globalLoop(0, 1, 3, 0, Pose2(0, 1, 0))).ok());
  EXPECT_EQ(m.view().loops().back().session_b, 3);
  EXPECT_EQ(m.view().list()[3].loops, 1);  // session 3 (ids 0, 1, 2, 3, 4)
  // Our odometry's next session, 4 (which our renamed session holds here), is a session of its own.
  ASSERT_TRUE(m.addKeyframe(keyframe(4, 0, Pose2(), Pose2())).ok());
  EXPECT_EQ(m.view().activeSession(), 5);
}

// A name made only of digits would read as an id wherever a name or an id is taken ("1" named a
// session while session 1 existed, and lookups found the wrong one): start_session refuses it,
// offline_slam names a folder "7" "./7", and digits name an id first (a store written before the
// rule may still hold such a name: found by it when no session has that id).
TEST(SessionManager, ANameMadeOnlyOfDigitsIsRefusedAndDigitsNameAnId) {
  testing_util::ScopedTempDir dir("session_manager");
  const std::string db = (dir.path() / "s.db").string();
  {
    SessionManager m(options(db));
    addStraightSession(&m, 0, 2);
    addStraightSession(&m, 1, 2);
    for (const std::string name : {"1", "0", "007", "999999999999"}) {
      const Status st = m.startSession(name, 5.0);
      EXPECT_EQ(st.code, StatusCode::kInvalidArgument) << name;
      EXPECT_NE(st.message.find("only of digits"), std::string::npos) << st.message;
    }
    EXPECT_EQ(m.view().sessionIds(), (std::vector<int>{0, 1}));
    EXPECT_EQ(m.view().activeSession(), 1);
    EXPECT_EQ(m.view().findSession("1"), 1);
    EXPECT_EQ(sessionNameOfFolder("7"), "./7");
    EXPECT_EQ(sessionNameOfFolder("/data/7"), "/data/7");
    EXPECT_EQ(sessionNameOfFolder("dive 7"), "dive 7");
    int id = -1;
    ASSERT_TRUE(m.startSession(sessionNameOfFolder("7"), 6.0, -1, &id).ok());
    addStraightSession(&m, id, 2);
    EXPECT_EQ(m.view().findSession("./7"), 2);
    ASSERT_TRUE(m.startSession("1a", 7.0).ok());
    addStraightSession(&m, 3, 2);
  }
  ASSERT_TRUE(testing_util::execSql(db, "UPDATE sessions SET name = '1' WHERE id = 0"));
  ASSERT_TRUE(testing_util::execSql(db, "UPDATE sessions SET name = '9' WHERE id = 3"));
  SessionManager m(options(db));
  EXPECT_EQ(m.view().findSession("1"), 1);  // the id, not session 0 named "1"
  EXPECT_EQ(m.view().findSession("0"), 0);
  EXPECT_EQ(m.view().findSession("9"), 3);  // no session 9: the older name
  EXPECT_EQ(m.view().findSession("./7"), 2);
  EXPECT_EQ(m.view().findSession("8"), -1);
}

// A link is between two keyframes that see the same seabed: no longer than the maps that hold
// them reach (their extents and what the two cameras see). A 1,000 km link with a 1 cm sigma
// (accepted before: only 1e7 m was a bound) is refused naming the bound; nothing changes.
TEST(SessionManager, ALinkLongerThanTheMapsCanHoldIsRefusedNamingTheBound) {
  SessionManager m(options());
  addStraightSession(&m, 0, 8);  // 7 m long
  addStraightSession(&m, 1, 4);  // 3 m long
  // 640 x 480 px, f = 500 px, 2 m up: 1.6 m from a keyframe to its image's corner on the seabed.
  EXPECT_NEAR(m.view().mapExtent(0), 7.0, 1e-9);
  EXPECT_NEAR(m.view().linkReach(0, 2, 1, 2), 7.0 + 3.0 + 2 * 1.6, 1e-9);
  EXPECT_NEAR(m.view().linkReach(0, 2, 0, 5), 7.0 + 2 * 1.6, 1e-9);  // one map counted once
  Loop far = globalLoop(0, 2, 1, 2, Pose2(1e6, 0, 0));
  far.z.covariance = Eigen::Matrix3d::Identity() * 1e-4;
  const Status st = m.addLink(far);
  EXPECT_EQ(st.code, StatusCode::kInvalidArgument) << st.message;
  EXPECT_NE(st.message.find("the link is 1e+06 m long"), std::string::npos) << st.message;
  EXPECT_NE(st.message.find("at most 13.2 m (map 0's extent 7 m, map 1's 3 m"), std::string::npos) << st.message;
  EXPECT_TRUE(m.view().loops().empty());
  Loop across = globalLoop(0, 2, 1, 2, Pose2(0, 13.1, 0));  // within the bound
  ASSERT_TRUE(m.addLink(across).ok());
  Loop beyond = globalLoop(0, 2, 1, 3, Pose2(0, 13.3, 0));
  EXPECT_EQ(m.addLink(beyond).code, StatusCode::kInvalidArgument);
  EXPECT_EQ(m.view().loops().size(), 1u);
}

// A clean close writes the WAL back into the store and cuts it to nothing, also while another
// connection to the file is open (a reader: an export, a tool, a monitor); SQLite did that only
// when the last connection closed, and the WAL stayed at its full size.
TEST(SessionManager, AStoreClosedCleanlyLeavesAnEmptyWalAlsoWithAReaderOpen) {
  testing_util::ScopedTempDir dir("session_manager");
  const std::string db = (dir.path() / "s.db").string();
  std::optional<SessionStore> reader;
  {
    SessionManager m(options(db));
    addStraightSession(&m, 0, 20);
    reader.emplace(db, StoreAccess::kReadOnly);
    ASSERT_EQ(reader->sessions().size(), 1u);
    EXPECT_GT(std::filesystem::file_size(db + "-wal"), 0u);
  }
  EXPECT_EQ(std::filesystem::file_size(db + "-wal"), 0u);
  EXPECT_EQ(reader->keyframes(0, false).size(), 20u);  // the reader reads it all, from the file
  reader.reset();
  EXPECT_EQ(SessionManager(options(db)).view().list()[0].keyframes, 20);
}

// A session start_session opened that no keyframe has followed: listed with 0 keyframes, and
// nothing of it stored until its first keyframe (no row left recording, no map saved for it);
// when the next session starts it is finished, and after a restart it is gone with nothing lost.
TEST(SessionManager, ASessionWithoutKeyframesIsListedEmptyAndNotStored) {
  testing_util::ScopedTempDir dir("session_manager");
  const std::string db = (dir.path() / "s.db").string();
  {
    SessionManager m(options(db));
    addStraightSession(&m, 0, 3);
    int empty = -1;
    ASSERT_TRUE(m.startSession("empty", 10.0, -1, &empty).ok());
    ASSERT_EQ(empty, 1);
    EXPECT_EQ(m.view().list()[1].keyframes, 0);
    EXPECT_EQ(m.view().list()[1].state, SessionState::kActive);
    m.flush();  // the maps saved: nothing of session 1
    int next = -1;
    ASSERT_TRUE(m.startSession("next", 11.0, -1, &next).ok());
    EXPECT_EQ(m.view().list()[1].state, SessionState::kFinished);
    EXPECT_EQ(m.view().list()[1].keyframes, 0);
    addStraightSession(&m, next, 2);
    ASSERT_TRUE(m.startSession("last", 20.0).ok());  // left without a keyframe at the end
    EXPECT_EQ(m.view().stats().store_failures, 0);
  }
  {
    const SessionStore store(db, StoreAccess::kReadOnly);
    std::vector<std::pair<std::int64_t, StoredSessionState>> rows;
    for (const StoredSession& s : store.sessions()) rows.emplace_back(s.id, s.state);
    EXPECT_EQ(rows, (std::vector<std::pair<std::int64_t, StoredSessionState>>{{0, StoredSessionState::kFinished},
                                                                              {2, StoredSessionState::kFinished}}));
  }
  SessionManager again(options(db));
  EXPECT_EQ(again.view().sessionIds(), (std::vector<int>{0, 2}));
  EXPECT_EQ(again.view().list()[1].keyframes, 2);
}

// The datum set at sea: kept in the store over a restart, and never written in localisation mode
// (the store stays byte-identical) nor without a store.
TEST(SessionManager, TheStoreKeepsTheDatumOverARestartExceptInLocalisationMode) {
  testing_util::ScopedTempDir dir("session_manager");
  const std::string db = (dir.path() / "s.db").string();
  {
    SessionManager m(options(db));
    addStraightSession(&m, 0, 3);
    EXPECT_FALSE(m.view().storedDatum());
    ASSERT_TRUE(m.storeDatum("43.1,5.9,90,0").ok());
  }
  const std::string before = fileBytes(db);
  {
    SessionManager m(options(db));
    ASSERT_TRUE(m.view().storedDatum());
    EXPECT_EQ(*m.view().storedDatum(), "43.1,5.9,90,0");
    ASSERT_TRUE(m.setLocalisation(true).ok());
    const Status refused = m.storeDatum("43.2,5.9,90,0");
    EXPECT_EQ(refused.code, StatusCode::kFailedPrecondition) << refused.message;
    EXPECT_NE(refused.message.find("localisation mode"), std::string::npos) << refused.message;
    EXPECT_EQ(*m.view().storedDatum(), "43.1,5.9,90,0");
  }
  EXPECT_EQ(fileBytes(db), before);
  SessionManager memory(options());
  EXPECT_FALSE(memory.view().storedDatum());
  EXPECT_EQ(memory.storeDatum("43.1,5.9,90,0").code, StatusCode::kFailedPrecondition);
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
