// StampGuard: duplicated, late, looping and gapped stamps (issue 9, bad input).
#include <gtest/gtest.h>

#include <limits>
#include <stdexcept>

#include "uw_multislam/core/frontend/stamp_guard.h"

namespace uw_multislam {
namespace core {
namespace {

TEST(StampGuard, ClassifiesEachKindOfBadTiming) {
  StampGuard g(StampGuardOptions{1.0, 10.0});
  EXPECT_EQ(g.accept(100.0), StampClass::kFirst);
  EXPECT_EQ(g.accept(100.5), StampClass::kNext);
  EXPECT_EQ(g.accept(100.5), StampClass::kDuplicate);   // the same frame twice
  EXPECT_EQ(g.accept(100.2), StampClass::kOutOfOrder);  // late by 0.3 s
  EXPECT_DOUBLE_EQ(g.last(), 100.5) << "skipped stamps are not accepted";
  EXPECT_EQ(g.accept(101.0), StampClass::kNext);
  EXPECT_EQ(g.accept(50.0), StampClass::kJumpBack);  // the bag looped
  EXPECT_DOUBLE_EQ(g.last(), 50.0);
  EXPECT_EQ(g.accept(50.5), StampClass::kNext);  // the new session goes on from there
  EXPECT_EQ(g.accept(70.0), StampClass::kJumpForward);
  EXPECT_EQ(g.accept(std::numeric_limits<double>::quiet_NaN()), StampClass::kOutOfOrder);
  EXPECT_DOUBLE_EQ(g.last(), 70.0);
}

TEST(StampGuard, BoundariesAndOff) {
  StampGuard g(StampGuardOptions{1.0, 0.0});  // forward jumps never start a session
  g.accept(10.0);
  EXPECT_EQ(g.accept(9.0), StampClass::kOutOfOrder) << "exactly the tolerance back is still late";
  EXPECT_EQ(g.accept(1e6), StampClass::kNext);
  StampGuard strict(StampGuardOptions{0.0, 5.0});
  strict.accept(10.0);
  EXPECT_EQ(strict.accept(9.99), StampClass::kJumpBack);
  EXPECT_EQ(strict.accept(14.99), StampClass::kNext);
  EXPECT_EQ(strict.accept(19.99 + 0.02), StampClass::kJumpForward);
  EXPECT_TRUE(StampGuard::skips(StampClass::kDuplicate));
  EXPECT_FALSE(StampGuard::skips(StampClass::kJumpBack));
  EXPECT_TRUE(StampGuard::startsSession(StampClass::kJumpBack));
  EXPECT_THROW(StampGuard(StampGuardOptions{-1.0, 1.0}), std::invalid_argument);
  EXPECT_EQ(stampClassName(StampClass::kOutOfOrder), "out_of_order");
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
