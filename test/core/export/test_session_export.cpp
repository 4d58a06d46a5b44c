// The back-end's export as a core request (export/session_export.h): every refusal with its
// code and nothing written, and the files of a session or its map from the store.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <memory>

#include "../../common/fixtures.h"
#include "../../common/scoped_temp_dir.h"
#include "uw_multislam/core/export/session_export.h"

namespace uw_multislam {
namespace core {
namespace {

namespace fs = std::filesystem;

KeyframeInput keyframe(int s, int k) {
  KeyframeInput in = testing_util::keyframeInput(
      s, k, Pose2(k, 0, 0), UncertainPose2(k == 0 ? Pose2() : Pose2(1, 0, 0), Eigen::Matrix3d::Identity() * 1e-4));
  in.frame_index = k;  // one frame a keyframe here
  return in;
}

SessionExportRequest request(const std::string& session, const std::string& folder = "out") {
  SessionExportRequest r;
  r.session = session;
  r.folder = folder;
  r.mosaic = false;  // the keyframes carry no image
  return r;
}

class SessionExportTest : public ::testing::Test {
 protected:
  SessionExportTest() : dir_("session_export") {
    root_ = (dir_.path() / "exports").string();
    fs::create_directories(root_);
    SessionManagerOptions o;
    o.store_path = (dir_.path() / "s.db").string();
    worker_ = std::make_unique<SessionWorker>(std::make_unique<SessionManager>(o), SessionWorkerOptions());
    for (int k = 0; k < 4; ++k) worker_->addKeyframe(keyframe(0, k));
    worker_->locked([](SessionManager& m) { return m.startSession("empty", 9.0); });  // no keyframe yet
  }
  /// Nothing below the root: a refusal writes nothing.
  bool rootEmpty() const { return fs::is_empty(root_); }

  testing_util::ScopedTempDir dir_;
  std::string root_;
  std::unique_ptr<SessionWorker> worker_;
};

TEST_F(SessionExportTest, BadArgumentsAreRefusedWithTheirCodesAndNothingWritten) {
  SessionExporter exporter(root_);
  SessionExport out;
  SessionExportRequest r = request("session_0");
  r.origin = "not,an,origin";
  EXPECT_EQ(exporter.run(*worker_, r, &out).code, StatusCode::kInvalidArgument);
  for (double bad : {-1.0, 100.5, std::nan("")}) {
    r = request("session_0");
    r.resolution_m = bad;
    const Status st = exporter.run(*worker_, r, &out);
    EXPECT_EQ(st.code, StatusCode::kInvalidArgument) << bad;
    EXPECT_NE(st.message.find("resolution_m"), std::string::npos) << st.message;
  }
  for (const char* outside : {"../elsewhere", "/tmp"}) {
    const Status st = exporter.run(*worker_, request("session_0", outside), &out);
    EXPECT_EQ(st.code, StatusCode::kInvalidArgument) << outside << ": " << st.message;
  }
  EXPECT_EQ(exporter.run(*worker_, request("no such session"), &out).code, StatusCode::kNotFound);
  EXPECT_EQ(exporter.run(*worker_, request("7"), &out).code, StatusCode::kNotFound);
  const Status empty = exporter.run(*worker_, request("empty"), &out);
  EXPECT_EQ(empty.code, StatusCode::kFailedPrecondition) << empty.message;
  EXPECT_NE(empty.message.find("no keyframe in the store"), std::string::npos) << empty.message;
  SessionExporter off("");
  const Status no_root = off.run(*worker_, request("session_0"), &out);
  EXPECT_EQ(no_root.code, StatusCode::kFailedPrecondition);
  EXPECT_NE(no_root.message.find("exports are off"), std::string::npos) << no_root.message;
  EXPECT_TRUE(out.files.empty());
  EXPECT_TRUE(rootEmpty());
  // Without a store there is nothing to export from.
  SessionWorker memory(std::make_unique<SessionManager>(SessionManagerOptions()), SessionWorkerOptions());
  memory.addKeyframe(keyframe(0, 0));
  EXPECT_EQ(exporter.run(memory, request("0"), &out).code, StatusCode::kFailedPrecondition);
  EXPECT_TRUE(rootEmpty());
}

TEST_F(SessionExportTest, ASessionsFilesAreWrittenBelowTheRootByNameOrId) {
  SessionExporter exporter(root_);
  SessionExport out;
  const Status st = exporter.run(*worker_, request("0", "dive/a"), &out);  // by id
  ASSERT_TRUE(st.ok()) << st.message;
  EXPECT_EQ(out.label, "session_0");
  EXPECT_EQ(out.name, "session_0");
  EXPECT_EQ(out.keyframes, 4u);
  EXPECT_EQ(fs::path(out.directory), fs::weakly_canonical(fs::path(root_) / "dive/a"));
  ASSERT_FALSE(out.files.empty());
  for (const std::string& f : out.files) {
    EXPECT_TRUE(fs::exists(f)) << f;
    EXPECT_EQ(fs::path(f).parent_path(), fs::path(out.directory)) << f;
    EXPECT_EQ(fs::path(f).stem(), "session_0") << f;
  }
  SessionExportRequest map = request("session_0", "dive/b");  // by name, its map
  map.map = true;
  ASSERT_TRUE(exporter.run(*worker_, map, &out).ok());
  EXPECT_EQ(out.label, "map_0");
  EXPECT_EQ(fs::path(out.files.front()).stem(), "map_0");
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
