// core::BoundedCalls (the back-end's calls to another vehicle's keyframe_features): a caller
// waits at most its deadline, a hung call holds its key (refused at once, not queued) until it
// returns, and nothing it touches dies under it.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <future>
#include <memory>
#include <stdexcept>
#include <thread>

#include "uw_multislam/core/common/bounded_call.h"

namespace uw_multislam {
namespace core {
namespace {

using Clock = std::chrono::steady_clock;

// Waits (with a deadline) until `calls` has no running call left.
bool awaitIdle(const BoundedCalls& calls, double deadline_s = 10.0) {
  const auto end = Clock::now() + std::chrono::duration<double>(deadline_s);
  while (calls.running() > 0) {
    if (Clock::now() > end) return false;
    std::this_thread::yield();
  }
  return true;
}

TEST(BoundedCalls, AnsweredCallsReturnTheirResult) {
  BoundedCalls calls;
  auto result = std::make_shared<int>(0);
  EXPECT_EQ(calls.call(
                "auv_b", [result] { *result = 42; }, 5.0),
            BoundedCalls::Outcome::kDone);
  EXPECT_EQ(*result, 42);
  EXPECT_EQ(calls.running(), 0);
  std::string why;
  EXPECT_EQ(calls.call(
                "auv_b", [] { throw std::runtime_error("link down"); }, 5.0, &why),
            BoundedCalls::Outcome::kThrew);
  EXPECT_EQ(why, "link down");
  EXPECT_EQ(calls.running(), 0);  // a call that threw holds nothing
  EXPECT_THROW(calls.call(
                   "auv_b", [] {}, 0.0),
               std::invalid_argument);
  EXPECT_THROW(calls.call(
                   "auv_b", [] {}, -1.0),
               std::invalid_argument);
}

TEST(BoundedCalls, CallsWithinTheirDeadlineRunSideBySideUnderOneKey) {
  BoundedCalls calls;
  auto gate = std::make_shared<std::promise<void>>();
  std::shared_future<void> open = gate->get_future().share();
  auto started = std::make_shared<std::promise<void>>();
  std::future<void> slow_started = started->get_future();
  std::future<BoundedCalls::Outcome> slow = std::async(std::launch::async, [&calls, open, started] {
    return calls.call(
        "auv_b",
        [open, started] {
          started->set_value();
          open.wait();
        },
        30.0);
  });
  ASSERT_EQ(slow_started.wait_for(std::chrono::seconds(10)), std::future_status::ready);
  // The slow call is still within its deadline: another request to the same vehicle is not refused.
  auto result = std::make_shared<int>(0);
  EXPECT_EQ(calls.call(
                "auv_b", [result] { *result = 3; }, 5.0),
            BoundedCalls::Outcome::kDone);
  EXPECT_EQ(*result, 3);
  gate->set_value();
  EXPECT_EQ(slow.get(), BoundedCalls::Outcome::kDone);
  EXPECT_EQ(calls.running(), 0);
}

TEST(BoundedCalls, AHungCallIsLeftAtItsDeadlineAndHoldsItsKeyUntilItReturns) {
  auto calls = std::make_unique<BoundedCalls>();
  auto gate = std::make_shared<std::promise<void>>();
  std::shared_future<void> open = gate->get_future().share();
  auto finished = std::make_shared<std::atomic<bool>>(false);
  const auto start = Clock::now();
  EXPECT_EQ(calls->call(
                "auv_b",
                [open, finished] {
                  open.wait();  // the other vehicle never answers, until the test says so
                  *finished = true;
                },
                0.05),
            BoundedCalls::Outcome::kTimedOut);
  const double waited = std::chrono::duration<double>(Clock::now() - start).count();
  EXPECT_GE(waited, 0.05);
  EXPECT_LT(waited, 5.0);  // the deadline, not the call (the call returns only when the gate opens)
  EXPECT_FALSE(*finished);
  EXPECT_EQ(calls->running(), 1);
  // The same vehicle again: refused at once, its function never run.
  auto started = std::make_shared<std::atomic<bool>>(false);
  EXPECT_EQ(calls->call(
                "auv_b", [started] { *started = true; }, 5.0),
            BoundedCalls::Outcome::kBusy);
  EXPECT_FALSE(*started);
  // Another vehicle is not held up by it.
  EXPECT_EQ(calls->call(
                "auv_c", [started] { *started = true; }, 5.0),
            BoundedCalls::Outcome::kDone);
  EXPECT_TRUE(*started);
  // The hung call returns: its key is free again.
  gate->set_value();
  ASSERT_TRUE(awaitIdle(*calls));
  EXPECT_TRUE(*finished);
  auto result = std::make_shared<int>(0);
  EXPECT_EQ(calls->call(
                "auv_b", [result] { *result = 7; }, 5.0),
            BoundedCalls::Outcome::kDone);
  EXPECT_EQ(*result, 7);

  // A call still hung when the object goes (the nodelet unloaded): it finishes later on its own.
  auto gate2 = std::make_shared<std::promise<void>>();
  std::shared_future<void> open2 = gate2->get_future().share();
  auto done2 = std::make_shared<std::promise<void>>();
  std::future<void> returned = done2->get_future();
  EXPECT_EQ(calls->call(
                "auv_b",
                [open2, done2] {
                  open2.wait();
                  done2->set_value();
                },
                0.01),
            BoundedCalls::Outcome::kTimedOut);
  calls.reset();
  gate2->set_value();
  EXPECT_EQ(returned.wait_for(std::chrono::seconds(10)), std::future_status::ready);
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
