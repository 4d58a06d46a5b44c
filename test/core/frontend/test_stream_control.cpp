// StreamControl: pause / resume and the back-end's session requests for the live odometry.
#include <gtest/gtest.h>

#include "uw_multislam/core/frontend/stream_control.h"

namespace uw_multislam {
namespace core {
namespace {

using Effect = StreamControl::Effect;

TEST(StreamControl, PauseAndResumeAreRefusedWhenAlreadyInThatState) {
  StreamControl c;
  EXPECT_FALSE(c.paused());
  EXPECT_FALSE(c.setPaused(false)) << "resume while running";
  EXPECT_TRUE(c.setPaused(true));
  EXPECT_TRUE(c.paused());
  EXPECT_FALSE(c.setPaused(true)) << "a second pause";
  EXPECT_TRUE(c.paused());
  EXPECT_EQ(c.countDropped(), 1);
  EXPECT_EQ(c.countDropped(), 2);
  EXPECT_TRUE(c.setPaused(false));
  EXPECT_FALSE(c.paused());
  EXPECT_EQ(c.droppedWhilePaused(), 2) << "kept across resume";
}

TEST(StreamControl, ARequestIsTakenOnceWithTheNextFreeId) {
  StreamControl c;
  StreamControl::Requested r = c.take();
  EXPECT_EQ(r.session, -1);
  EXPECT_EQ(r.next_free, 0);
  EXPECT_EQ(c.request(3, 4, false, false), Effect::kNone);
  r = c.take();
  EXPECT_EQ(r.session, 3);
  EXPECT_EQ(r.next_free, 4);
  r = c.take();
  EXPECT_EQ(r.session, -1) << "taken once";
  EXPECT_EQ(r.next_free, 4);
}

TEST(StreamControl, AnotherVehiclesIdOnlyMovesTheNextFreeIdOnceARequestWasTaken) {
  StreamControl first;  // a subscriber that comes now takes the request the message repeats
  first.request(2, 5, true, false);
  EXPECT_EQ(first.take().session, 2);
  StreamControl c;
  c.request(0, 1, false, false);
  c.take();
  EXPECT_EQ(c.request(0, 7, true, false), Effect::kNone);
  const StreamControl::Requested r = c.take();
  EXPECT_EQ(r.session, -1);
  EXPECT_EQ(r.next_free, 7);
}

TEST(StreamControl, AFinishedSessionPausesUntilTheNextRequestOrResume) {
  StreamControl c;
  EXPECT_EQ(c.request(0, 1, false, true), Effect::kPausedByFinish);
  EXPECT_TRUE(c.paused());
  EXPECT_EQ(c.request(1, 2, false, false), Effect::kResumedAfterFinish);
  EXPECT_FALSE(c.paused());
  EXPECT_EQ(c.take().session, 1);
  // resume after finish: running again, and a later request changes no pause.
  c.request(1, 2, false, true);
  EXPECT_TRUE(c.setPaused(false));
  EXPECT_EQ(c.request(2, 3, false, false), Effect::kNone);
  EXPECT_FALSE(c.paused());
  // An operator's pause is not ended by a request.
  EXPECT_TRUE(c.setPaused(true));
  EXPECT_EQ(c.request(3, 4, false, false), Effect::kNone);
  EXPECT_TRUE(c.paused());
}

TEST(StreamControl, SessionStartsInOrderOfPrecedence) {
  const StampClass next = StampClass::kNext, back = StampClass::kJumpBack, forward = StampClass::kJumpForward;
  StreamControl::Requested none, asked;
  none.next_free = 0;
  asked.session = 9, asked.next_free = 10;
  // The first frame: the requested id, else the current one (~session).
  EXPECT_EQ(sessionStart(true, 4, none, next, 0.0, false).id, 4);
  EXPECT_EQ(sessionStart(true, 4, asked, back, 0.0, true).id, 9);
  EXPECT_TRUE(sessionStart(true, 4, none, next, 0.0, false).starts());
  // A request of another id comes before a jump or a new camera; the same id starts nothing.
  EXPECT_EQ(sessionStart(false, 4, asked, forward, 20.0, true).id, 9);
  EXPECT_EQ(sessionStart(false, 4, asked, forward, 20.0, true).cause, SessionStart::Cause::kRequested);
  StreamControl::Requested same = asked;
  same.session = 4;
  EXPECT_FALSE(sessionStart(false, 4, same, next, 0.0, false).starts());
  // A jump or a new camera: the next id, past those other vehicles took.
  const SessionStart jump = sessionStart(false, 4, none, back, -30.0, false);
  EXPECT_TRUE(jump.starts());
  EXPECT_EQ(jump.id, 5);
  EXPECT_NE(jump.why.find("jumped"), std::string::npos);
  StreamControl::Requested taken;
  taken.next_free = 12;
  EXPECT_EQ(sessionStart(false, 4, taken, forward, 20.0, false).id, 12);
  const SessionStart camera = sessionStart(false, 4, none, next, 0.0, true);
  EXPECT_EQ(camera.id, 5);
  EXPECT_EQ(camera.why, "camera intrinsics changed");
  EXPECT_FALSE(sessionStart(false, 4, none, next, 0.0, false).starts());
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
