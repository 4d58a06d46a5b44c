#!/usr/bin/python3
"""rostest: sessions that change while a bag plays through slam.launch.

The case comes from the private parameter ~case (live_sessions.test registers it once per case, so
each runs against a fresh pipeline and the cases do not depend on each other's order):

start_session  The fixture's session s0 is played; once its first keyframes have arrived, the test
               calls start_session. The next keyframe the odometry publishes is the new session's
               origin (keyframe 0, status FIRST, odometry pose (0, 0, 0)), every later keyframe of
               the bag belongs to it, and no keyframe of the old session follows it.
tracking_loss  One session flown over two laps with seven blank frames in the first lap (the
               offline test_offline_slam.py tracking-loss mission, at 240 x 180): tracking is lost,
               the odometry closes session 0 and starts session 1 when the seabed is back, and the
               second lap's global loops join the two again in one map, within 5 cm of the truth.
pause          The operator's pause / resume on the odometry: the test publishes a
               one-session mission frame by frame (each awaited: its odometry pose, or for a frame
               sent while paused the count of frames dropped on /diagnostics). Frames sent while
               paused are dropped and counted (no pose, no keyframe), the session goes on after
               resume (one session, no time jump, no tracking loss); pause while paused and resume
               while running are refused with FAILED_PRECONDITION and change nothing.
finish         finish_session on the same mission: session 0 FINISHED with every keyframe sent
               before it, frames dropped until resume, the first frame after resume the origin of
               session 1; a second finish_session is refused (nothing records).
"""
import csv
import math
import os
import shutil
import subprocess
import threading
import time
import unittest

import rospy
import rostest
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import Path
from sensor_msgs.msg import CameraInfo, Image, Range
from pipeline_fixture import (NS, SENSOR_TOPICS, appender, await_condition, bag_frames, connected, DiagnosticsWatch,
                              make_mission, vehicle_from_camera, wait_for_subscribers)
from uw_multislam.msg import Keyframe, Loop, SessionState, SlamStatus, Status
from uw_multislam.srv import FinishSession, ListSessions, OperatorCommand, StartSession

PLAY_RATE = 4.0  # frames per second: far below the odometry's speed on 240 x 180 images
KEYFRAMES_BEFORE_START = 4  # session 0's keyframes received before start_session is called
# test_offline_slam.py's LOST mission with the fixture's small camera: frames 10-16 blank.
LOST = """
seed: 3
world: {width_m: 12, height_m: 10, featureless_fraction: 0}
sessions:
  - name: a
    camera: {image_width: 240, image_height: 180, fx: 220, fy: 220, cx: 119.5, cy: 89.5}
    mission: {pattern: loop, start_m: [3.5, 2.5], length_m: 4.0, width_m: 3.0, laps: 2.1,
              speed_m_s: 0.4, frame_period_s: 1.0, altitude_m: 2.0}
    water:
      stretches:
        - {first_frame: 10, num_frames: 7, kind: blank}
"""
BLANK = range(10, 17)
# One session at 2 frames per second (0.175 m between frames: three frames dropped leave the
# next frame well inside the last keyframe's footprint, so the pause alone is what is tested).
PAUSE_MISSION = """
seed: 5
world: {width_m: 12, height_m: 10, metres_per_px: 0.008, featureless_fraction: 0.0}
sessions:
  - name: a
    camera: {image_width: 240, image_height: 180, fx: 220, fy: 220, cx: 119.5, cy: 89.5}
    mission: {pattern: loop, start_m: [6.0, 5.0], length_m: 3.5, width_m: 2.5, laps: 0.5, speed_m_s: 0.35,
              frame_period_s: 0.5, altitude_m: 1.6, start_time_s: 0}
"""
PAUSED = range(10, 13)  # the frames sent while paused
# Offline, the same mission's joined keyframes are within 5 cm of the truth (test_offline_slam.py).
JOINED_TOLERANCE_M = 0.05


class LiveSessionsTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.case = rospy.get_param("~case")
        cls.lock = threading.Lock()
        cls.keyframes, cls.loops, cls.paths = [], [], {}

        def on_keyframe(msg):
            with cls.lock:
                cls.keyframes.append(msg)

        def on_loop(msg):
            with cls.lock:
                cls.loops.append(msg)

        cls.statuses = []
        cls.subs = [rospy.Subscriber(NS + "/keyframes", Keyframe, on_keyframe, queue_size=1000),
                    rospy.Subscriber(NS + "/loops", Loop, on_loop, queue_size=1000),
                    rospy.Subscriber(NS + "/status", SlamStatus, appender(cls.lock, cls.statuses), queue_size=1000)]
        for srv in ("list_sessions", "start_session"):
            rospy.wait_for_service(NS + "/" + srv, timeout=60)
        cls.list = rospy.ServiceProxy(NS + "/list_sessions", ListSessions)
        cls.start = rospy.ServiceProxy(NS + "/start_session", StartSession)
        wait_for_subscribers(SENSOR_TOPICS + [NS + "/keyframes"], "/check_live_sessions")
        if cls.case == "tracking_loss":
            cls.tmp, cls.mission = make_mission("uwms_live_sessions_", LOST)
        elif cls.case in ("pause", "finish"):
            cls.tmp, cls.mission = make_mission("uwms_live_sessions_", PAUSE_MISSION)
        else:
            cls.tmp, cls.mission = make_mission("uwms_live_sessions_")

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def sessions(self):
        res = self.list()
        self.assertEqual(res.status.code, Status.OK)
        return {s.session: s for s in res.sessions}

    def states(self):
        """The status topic's (state, session) in the order published, repeats dropped."""
        out = []
        with self.lock:
            for s in self.statuses:
                if not out or out[-1] != (s.state, s.session):
                    out.append((s.state, s.session))
        return out

    def assert_states_in_order(self, expected):
        """`expected` (state, session) pairs are among the status's states, in this order."""
        states = self.states()
        names = {v: k for k, v in vars(SlamStatus).items() if k.isupper() and isinstance(v, int)}
        at = 0
        for e in expected:
            while at < len(states) and states[at] != e:
                at += 1
            self.assertLess(at, len(states), "status states %s do not hold %s in order" % (
                [(names.get(s, s), n) for s, n in states], [(names[s], n) for s, n in expected]))

    def play(self, bag):
        return subprocess.Popen(["rosbag", "play", "-q", "--wait-for-subscribers", "-d", "1", "-r", str(PLAY_RATE), bag,
                                 "--topics"] + SENSOR_TOPICS)

    def wait_for_bag(self, play, timeout=180):
        self.assertEqual(play.wait(timeout=timeout), 0, "rosbag play failed")

    def await_listed(self, condition, timeout, what):
        """list_sessions once condition(sessions) holds (polled every 0.2 s), else a failure naming what."""
        deadline = time.time() + timeout
        listed = self.sessions()
        while not condition(listed) and time.time() < deadline:
            time.sleep(0.2)
            listed = self.sessions()
        self.assertTrue(condition(listed), "timed out after %.0f s waiting for %s: %s" % (
            timeout, what, [(s.session, s.state, s.map, s.num_keyframes) for s in listed.values()]))
        return listed

    def test_live_session_case(self):
        if self.case == "start_session":
            self.start_session_while_a_bag_plays()
        elif self.case == "tracking_loss":
            self.tracking_loss_gives_two_sessions_that_global_loops_join()
        elif self.case == "pause":
            self.pause_drops_frames_and_the_session_goes_on()
        elif self.case == "finish":
            self.finish_session_ends_it_and_resume_starts_the_next()
        else:
            self.fail("unknown ~case %r" % self.case)

    def start_session_while_a_bag_plays(self):
        play = self.play(os.path.join(self.mission, "s0.bag"))
        try:
            await_condition(self.lock, lambda: len(self.keyframes) >= KEYFRAMES_BEFORE_START, 90,
                            "session 0's first %d keyframes" % KEYFRAMES_BEFORE_START,
                            lambda: ": %d keyframes" % len(self.keyframes))
            res = self.start("mid_bag")
            self.assertEqual(res.status.code, Status.OK, res.status.message)
            new = res.session
            with self.lock:
                at_call = len(self.keyframes)
            self.assertGreater(new, 0)
            # The next keyframe of the new session (the odometry hears of it on active_session).
            await_condition(self.lock, lambda: any(k.session == new for k in self.keyframes), 90,
                            "a keyframe of session %d" % new,
                            lambda: ": sessions %s" % sorted({k.session for k in self.keyframes}))
            self.wait_for_bag(play)
        finally:
            if play.poll() is None:
                play.kill()
        # Until the back-end holds every keyframe the odometry published.
        with self.lock:
            published = {s: len([k for k in self.keyframes if k.session == s]) for s in (0, new)}
        self.await_listed(lambda l: new in l and l[new].num_keyframes == published[new]
                          and l[0].num_keyframes == published[0], 60, "the back-end to hold every keyframe")
        with self.lock:
            order = [(k.session, k.keyframe) for k in self.keyframes]
            first = next(k for k in self.keyframes if k.session == new)
        self.assertEqual({s for s, _ in order}, {0, new}, order)
        switch = order.index((new, 0)) if (new, 0) in order else -1
        self.assertGreaterEqual(switch, KEYFRAMES_BEFORE_START, order)
        # Session 0's keyframes, then the new session's: none of session 0 after the new origin
        # (those in flight when the call was answered arrive before it).
        self.assertEqual(order, [(0, i) for i in range(switch)] + [(new, i) for i in range(len(order) - switch)],
                         "keyframes in the order received (the call was answered after %d)" % at_call)
        self.assertEqual(first.keyframe, 0)
        self.assertEqual(first.status, Keyframe.FIRST)
        self.assertEqual((first.odometry_pose.x, first.odometry_pose.y, first.odometry_pose.theta), (0.0, 0.0, 0.0))
        self.assertGreaterEqual(published[new], 5, "the rest of the bag went to session %d" % new)
        listed = self.sessions()
        self.assertEqual(listed[0].state, SessionState.FINISHED)
        self.assertEqual(listed[new].state, SessionState.ACTIVE)
        self.assertEqual(listed[new].name, "mid_bag")
        # Its path starts at its origin: in its own frame, or where a join placed that origin.
        path = rospy.wait_for_message(NS + "/paths/session_%d" % new, Path, timeout=30)
        self.assertEqual(path.poses[0].header.stamp, first.header.stamp)
        print("start_session after %d keyframes of session 0: session %d's origin is the keyframe at %.1f s, "
              "%d keyframes of session 0, %d of session %d" % (at_call, new, first.header.stamp.to_sec(),
                                                             published[0], published[new], new))

    def tracking_loss_gives_two_sessions_that_global_loops_join(self):
        self.wait_for_bag(self.play(os.path.join(self.mission, "a.bag")))
        # One bag, one odometry: two sessions (lost in the blank stretch), both in map 0 once the
        # second lap's global loops have joined them.
        listed = self.await_listed(lambda l: sorted(l) == [0, 1] and l[1].map == l[0].map == 0 and
                                   l[1].num_keyframes == len([k for k in self.keyframes if k.session == 1]) > 0,
                                   90, "sessions 0 and 1 joined in map 0")
        with self.lock:
            keyframes = list(self.keyframes)
            loops = list(self.loops)
        self.assertEqual({k.session for k in keyframes}, {0, 1})
        # Frame indexes from the stamps: the bag's frames are 1 s apart from session 0's first keyframe (frame 0).
        t0 = min(k.header.stamp.to_sec() for k in keyframes)
        stamps = {s: [round(k.header.stamp.to_sec() - t0) for k in keyframes if k.session == s] for s in (0, 1)}
        self.assertLess(max(stamps[0]), BLANK.start, "session 0 ends before the blank frames")
        self.assertGreaterEqual(min(stamps[1]), BLANK.stop, "session 1 starts when the seabed is back")
        self.assertEqual(listed[0].state, SessionState.FINISHED)
        self.assertEqual(listed[0].num_keyframes, len(stamps[0]))
        global_loops = [l for l in loops if l.kind == Loop.GLOBAL and {l.session_a, l.session_b} == {0, 1}]
        self.assertGreaterEqual(len(global_loops), 3, "global loops between the two pieces")
        # Both pieces in map 0 (session 0's frame, the first frame's), against the ground truth.
        with open(os.path.join(self.mission, "a", "gt.csv")) as f:
            truth = {int(r["index"]): (float(r["x_m"]), float(r["y_m"]), float(r["yaw_rad"])) for r in csv.DictReader(f)}
        worst = 0.0
        for s in (0, 1):
            # Latched, and published again after the join: the last one holds the joined poses.
            path = rospy.wait_for_message(NS + "/paths/session_%d" % s, Path, timeout=30)
            self.assertEqual(len(path.poses), len(stamps[s]))
            for p in path.poses:
                x, y, _ = vehicle_from_camera(truth[round(p.header.stamp.to_sec() - t0)])
                worst = max(worst, math.hypot(p.pose.position.x - x, p.pose.position.y - y))
        print("tracking loss: session 0 frames %d-%d (%d keyframes), session 1 frames %d-%d (%d keyframes), "
              "%d global loops between them, joined keyframes worst %.4f m from the truth" % (
                  min(stamps[0]), max(stamps[0]), len(stamps[0]), min(stamps[1]), max(stamps[1]), len(stamps[1]),
                  len(global_loops), worst))
        self.assertLess(worst, JOINED_TOLERANCE_M)
        # The status followed it: tracking session 0, lost, tracking session 1; then, joined, session
        # 1 in map 0 (the last status the back-end published once the join was listed).
        self.assert_states_in_order([(SlamStatus.TRACKING, 0), (SlamStatus.LOST, 0), (SlamStatus.TRACKING, 1)])
        def counted(last):  # every keyframe received so far (the odometry may still be finishing the bag)
            return last.map == 0 and last.maps == 1 and last.keyframes == len(self.keyframes) and \
                last.session_keyframes == len([k for k in self.keyframes if k.session == 1])
        await_condition(self.lock, lambda: counted(self.statuses[-1]), 30,
                        "a status with session 1 in map 0 and every keyframe", lambda: ": %s" % self.statuses[-1])
        with self.lock:
            last = self.statuses[-1]
        self.assertEqual((last.session, last.sessions, last.tracking_losses), (1, 2, 1))
        self.assertGreater(last.loops, 0)
        self.assertTrue(0.0 <= last.last_loop_age_s < 60.0, last.last_loop_age_s)  # loops came during the bag
        print("status: %s; last: %s" % (self.states(), last.text))

    def frame_by_frame(self):
        """Subscriptions to odometry/pose and the odometry's /diagnostics, publishers of the sensor
        topics, the mission's frames; and send(i, dropped): frame i published and awaited, by its
        pose, or (dropped = the paused count it must make) by the odometry's frames_dropped_paused."""
        poses = []
        subs = [rospy.Subscriber(NS + "/odometry/pose", PoseWithCovarianceStamped, appender(self.lock, poses),
                                 queue_size=1000),
                DiagnosticsWatch(("odometry",), self.lock)]

        def status():  # the odometry's newest
            return subs[-1].get("odometry")

        pubs = [rospy.Publisher(t, m, queue_size=100) for t, m in zip(SENSOR_TOPICS, (Image, CameraInfo, Range))]
        await_condition(self.lock, lambda: connected(pubs) and status(), 30,
                        "the odometry's subscriptions and diagnostics")
        frames = bag_frames(os.path.join(self.mission, "a.bag"))
        self.assertGreater(len(frames), PAUSED.stop + 5)

        def send(i, dropped=None):
            image, info, altitude = frames[i]
            pubs[2].publish(altitude)
            pubs[1].publish(info)
            pubs[0].publish(image)
            stamp = image.header.stamp
            if dropped is not None:
                await_condition(self.lock, lambda: status().get("frames_dropped_paused") == dropped and
                                status().get("frames_finished") == i + 1, 30, "frame %d dropped while paused" % i,
                                lambda: ": %s" % status())
                with self.lock:
                    self.assertEqual(status().get("paused"), 1.0)
            else:
                await_condition(self.lock, lambda: any(p.header.stamp == stamp for p in poses), 30,
                                "the odometry pose of frame %d" % i, lambda: ": %d poses" % len(poses))

        def finished():
            await_condition(self.lock, lambda: status().get("frames_finished") == len(frames) and
                            status().get("keyframes") == len(self.keyframes), 30, "the last frame finished",
                            lambda: ": %s" % status())
            for s in subs:
                s.unregister()
            with self.lock:
                return dict(status()), [p.header.stamp for p in poses], list(self.keyframes)

        return frames, send, finished

    def pause_drops_frames_and_the_session_goes_on(self):
        frames, send, finished = self.frame_by_frame()
        rospy.wait_for_service(NS + "/pause", timeout=30)
        pause = rospy.ServiceProxy(NS + "/pause", OperatorCommand)
        resume = rospy.ServiceProxy(NS + "/resume", OperatorCommand)
        # Called wrong: resume while running.
        r = resume()
        self.assertEqual(r.status.code, Status.FAILED_PRECONDITION)
        self.assertIn("not paused", r.status.message)
        self.assertFalse(r.paused)
        self.assertEqual(r.frames_dropped_paused, 0)
        for i in range(len(frames)):
            if i == PAUSED.start:
                r = pause()
                self.assertEqual(r.status.code, Status.OK, r.status.message)
                self.assertTrue(r.paused)
                again = pause()  # called wrong: already paused; still paused
                self.assertEqual(again.status.code, Status.FAILED_PRECONDITION)
                self.assertIn("already paused", again.status.message)
                self.assertTrue(again.paused)
            if i == PAUSED.stop:
                r = resume()
                self.assertEqual(r.status.code, Status.OK, r.status.message)
                self.assertFalse(r.paused)
                self.assertEqual(r.frames_dropped_paused, len(PAUSED))
            send(i, i - PAUSED.start + 1 if i in PAUSED else None)
            if i == PAUSED.start:  # the status says so at once (the odometry's state changed)
                await_condition(self.lock, lambda: self.statuses and self.statuses[-1].state == SlamStatus.PAUSED, 10,
                                "a PAUSED status", lambda: ": %s" % self.states())
        final, stamps, keyframes = finished()
        self.assert_states_in_order([(SlamStatus.TRACKING, 0), (SlamStatus.PAUSED, 0), (SlamStatus.TRACKING, 0)])
        paused = {frames[i][0].header.stamp for i in PAUSED}
        self.assertEqual(len(stamps), len(frames) - len(PAUSED), "a pose for every frame not paused")
        self.assertFalse(paused & set(stamps), "no pose for a paused frame")
        self.assertFalse(paused & {k.header.stamp for k in keyframes}, "no keyframe from a paused frame")
        self.assertEqual({k.session for k in keyframes}, {0}, "one session through the pause")
        self.assertGreater(len([k for k in keyframes if k.header.stamp > frames[PAUSED.stop][0].header.stamp]), 0,
                           "keyframes after resume")
        self.assertEqual(final["frames_dropped_paused"], len(PAUSED))
        self.assertEqual(final["paused"], 0.0)
        for key in ("time_jumps_forward", "tracking_losses", "fallbacks", "dropped_queue_full"):
            self.assertEqual(final[key], 0, key)
        listed = self.await_listed(lambda l: sorted(l) == [0] and l[0].num_keyframes == len(keyframes), 30,
                                   "session 0 with every keyframe")
        self.assertEqual(listed[0].state, SessionState.ACTIVE)
        print("pause: %d frames, %d dropped while paused (frames %d-%d), %d poses, %d keyframes, one session" % (
            len(frames), final["frames_dropped_paused"], PAUSED.start, PAUSED.stop - 1, len(stamps), len(keyframes)))

    def finish_session_ends_it_and_resume_starts_the_next(self):
        frames, send, finished = self.frame_by_frame()
        rospy.wait_for_service(NS + "/finish_session", timeout=30)
        finish = rospy.ServiceProxy(NS + "/finish_session", FinishSession)
        resume = rospy.ServiceProxy(NS + "/resume", OperatorCommand)
        for i in range(len(frames)):
            if i == PAUSED.start:
                # The back-end holds every keyframe sent so far (one in flight when finish_session is
                # answered would be skipped as stale: README, finish_session).
                self.await_listed(lambda l: sorted(l) == [0] and l[0].num_keyframes == len(self.keyframes) > 0, 30,
                                  "the back-end to hold every keyframe of session 0 sent so far")
                with self.lock:
                    sent = len(self.keyframes)
                r = finish()
                self.assertEqual(r.status.code, Status.OK, r.status.message)
                self.assertEqual(r.session, 0)
                again = finish()  # called wrong: nothing records now; nothing changes
                self.assertEqual(again.status.code, Status.FAILED_PRECONDITION)
                self.assertIn("no session is recording", again.status.message)
                self.assertEqual(again.session, -1)
                listed = self.sessions()
                self.assertEqual(sorted(listed), [0])
                self.assertEqual(listed[0].state, SessionState.FINISHED)
            if i == PAUSED.stop:
                r = resume()
                self.assertEqual(r.status.code, Status.OK, r.status.message)
            send(i, i - PAUSED.start + 1 if i in PAUSED else None)
        final, stamps, keyframes = finished()
        before = len([k for k in keyframes if k.session == 0])
        self.assertEqual(before, sent)
        first = keyframes[before]
        self.assertEqual([k.session for k in keyframes], [0] * before + [1] * (len(keyframes) - before))
        self.assertEqual((first.session, first.keyframe, first.status), (1, 0, Keyframe.FIRST))
        self.assertEqual(first.header.stamp, frames[PAUSED.stop][0].header.stamp, "the first frame after resume")
        self.assertEqual(final["frames_dropped_paused"], len(PAUSED))
        self.assertEqual(len(stamps), len(frames) - len(PAUSED))
        listed = self.await_listed(lambda l: sorted(l) == [0, 1] and l[1].num_keyframes == len(keyframes) - before,
                                   30, "session 1 with every keyframe after resume")
        self.assertEqual(listed[0].num_keyframes, before, "session 0 kept every keyframe sent before finish")
        self.assertEqual(listed[0].state, SessionState.FINISHED)
        self.assertEqual(listed[1].state, SessionState.ACTIVE)
        print("finish_session after frame %d: session 0 FINISHED with %d keyframes, %d frames dropped, session 1 "
              "from frame %d with %d keyframes" % (PAUSED.start - 1, before, final["frames_dropped_paused"],
                                                   PAUSED.stop, len(keyframes) - before))

if __name__ == "__main__":
    rospy.init_node("check_live_sessions")
    rostest.rosrun("uw_multislam", "check_live_sessions", LiveSessionsTest)
