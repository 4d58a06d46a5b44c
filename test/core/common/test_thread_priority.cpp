// setThisThreadNice (core/common/thread_priority.h): a thread's own nice value, not its process's.
#include <gtest/gtest.h>

#include <string>
#include <thread>

#include "uw_multislam/core/common/thread_priority.h"

namespace uw_multislam {
namespace core {
namespace {

TEST(ThreadPriority, LowersOnlyTheCallingThread) {
  const int before = thisThreadNice();
  if (before >= 19) GTEST_SKIP() << "this test runs at nice " << before << ": nothing lower to set";
  int inside = -100;
  bool ok = false;
  std::string why;
  std::thread t([&] {
    ok = setThisThreadNice(before + 1, &why);
    inside = thisThreadNice();
  });
  t.join();
  EXPECT_TRUE(ok) << why;
  EXPECT_EQ(inside, before + 1);
  EXPECT_EQ(thisThreadNice(), before) << "the other threads keep theirs";
}

TEST(ThreadPriority, RefusesWhatItCannotOrMustNotSet) {
  std::string why;
  EXPECT_FALSE(setThisThreadNice(-1, &why));  // raising needs a privilege: not offered
  EXPECT_NE(why.find("[0, 19]"), std::string::npos) << why;
  EXPECT_FALSE(setThisThreadNice(20, &why));
  const int before = thisThreadNice();
  EXPECT_TRUE(setThisThreadNice(0, &why));  // 0: left as it is
  EXPECT_EQ(thisThreadNice(), before);
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
