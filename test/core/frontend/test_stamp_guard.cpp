// StampGuard: duplicated, late, looping and gapped stamps (bad input).
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

TEST(StampGuard, StampsPassedOverBridgeTheGapOurOwnDropsLeave) {
  // A 10 Hz burst of 1,000 frames of which the node's own queue kept one in 50:
  // the kept frames are 5 s apart, more than session_gap_s, but the camera never paused.
  StampGuard g(StampGuardOptions{1.0, 2.0});
  StampGuard without(StampGuardOptions{1.0, 2.0});  // the same frames, the drops not passed over
  int jumps = 0, jumps_without = 0;
  for (int i = 0; i < 1000; ++i) {
    const double t = 1000.0 + 0.1 * i;
    if (i % 50 != 0) {
      g.passOver(t);  // dropped: seen, not processed
      continue;
    }
    jumps += StampGuard::startsSession(g.accept(t));
    jumps_without += StampGuard::startsSession(without.accept(t));
  }
  EXPECT_EQ(jumps, 0);
  EXPECT_EQ(jumps_without, 19) << "the scenario must produce gaps when the drops are ignored";
  // A real pause of the camera among the dropped frames is still a gap: the next processed frame
  // starts the session, and lastJump() says by how much the stamps jumped.
  EXPECT_EQ(g.accept(1100.0), StampClass::kNext);
  g.passOver(1100.1);
  g.passOver(1130.0);  // the camera paused 29.9 s
  g.passOver(1130.1);
  EXPECT_EQ(g.accept(1130.2), StampClass::kJumpForward);
  EXPECT_NEAR(g.lastJump(), 29.9, 1e-9);
  EXPECT_EQ(g.accept(1130.3), StampClass::kNext);  // reported once
  // A jump back among the dropped frames (a bag that loops) likewise.
  g.passOver(500.0);
  EXPECT_EQ(g.accept(500.1), StampClass::kJumpBack);
  EXPECT_NEAR(g.lastJump(), -630.3, 1e-9);
  // Passed-over duplicates, late and non-finite stamps change nothing; the frame after them is
  // classified against the last stamp.
  g.passOver(500.1);
  g.passOver(499.9);
  g.passOver(std::numeric_limits<double>::quiet_NaN());
  EXPECT_DOUBLE_EQ(g.last(), 500.1);
  EXPECT_EQ(g.accept(500.1), StampClass::kDuplicate);
  EXPECT_EQ(g.accept(500.2), StampClass::kNext);
  // A duplicate of a passed-over stamp is the same frame again: skipped, the held jump kept for
  // the next frame.
  g.passOver(600.0);
  EXPECT_EQ(g.accept(600.0), StampClass::kDuplicate);
  EXPECT_EQ(g.accept(600.1), StampClass::kJumpForward);
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
