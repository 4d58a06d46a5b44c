#include "uw_multislam/core/common/status.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <string>

namespace uw_multislam {
namespace core {
namespace {

namespace fs = std::filesystem;

// Answers name files by role: each path goes, the longer first, so that a file inside the export
// root keeps its name under the root's role, and the code stays.
TEST(Status, WithRolesReplacesEveryPathByItsRoleLongestFirst) {
  const Status s{StatusCode::kNotFound,
                 "session store /data/a.db: keyframe 3 is not stored; /data/a.db again; "
                 "/data/exports/ok/x.tum outside /data/exports"};
  const Status out = withRoles(s, {{"/data/exports", "the export root"}, {"/data/a.db", "the store"}, {"", "nothing"}});
  EXPECT_EQ(out.code, StatusCode::kNotFound);
  EXPECT_EQ(out.message,
            "session store the store: keyframe 3 is not stored; the store again; the export root/ok/x.tum outside "
            "the export root");
  // A role that holds its own path is not replaced again (no endless loop).
  EXPECT_EQ(withRoles({StatusCode::kInternal, "/a /a"}, {{"/a", "/a/b"}}).message, "/a/b /a/b");
}

// The store and the export root as the core's messages may name them: as given (relative), absolute,
// through a symlink resolved, with the words before them. None of the paths may remain.
TEST(Status, PathRolesCoverTheGivenResolvedAndAbsoluteForms) {
  const fs::path dir = fs::temp_directory_path() / ("uwms_path_roles_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir / "real");
  fs::create_directory_symlink(dir / "real", dir / "link");
  const fs::path cwd = fs::current_path();
  fs::current_path(dir);
  const std::string store = "link/s.db", root = "exports";
  const std::string real = (dir / "real" / "s.db").string(), absolute_root = (dir / "exports").string();
  const Status s{StatusCode::kFailedPrecondition, "session store " + real + " is held; export root '" + absolute_root +
                                                      "': missing; " + store + " and 'exports' named as given"};
  const std::string out = withRoles(s, pathRoles(store, root)).message;
  fs::current_path(cwd);
  fs::remove_all(dir);
  EXPECT_EQ(out, "the store is held; the export root: missing; the store and the export root named as given");
  EXPECT_TRUE(pathRoles("", "").empty());
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
