#include "uw_multislam/core/common/status.h"

#include <gtest/gtest.h>

namespace uw_multislam {
namespace core {
namespace {

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

}  // namespace
}  // namespace core
}  // namespace uw_multislam
