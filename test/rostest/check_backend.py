#!/usr/bin/python3
"""rostest: the back-end / session manager in slam.launch on a generated two-session mission.

The bags are generated at test time (make_survey, small images) and played one after the other;
the second session's stamps start 1000 s later, so the odometry starts session 1 by its stamp gap
rule. Automatic joining is off (join_min_loops 0): the test joins the sessions with join_sessions,
checks the joined trajectory against the ground truth, splits them again, and makes wrong calls.
"""
import csv
import heapq
import math
import os
import shutil
import subprocess
import sys
import threading
import time
import unittest

import rosgraph
import rosnode
import rospy
import rostest
from pipeline_fixture import (NS, SENSOR_TOPICS, backend_values, connected, frames_by_stamp, make_mission,
                              wait_for_subscribers, wait_until_quiet)
from nav_msgs.msg import Path
from uw_multislam.msg import Keyframe, Loop, SessionState, Status
from uw_multislam.srv import JoinSessions, ListSessions, SplitSession, StartSession, ReloadSession
from visualization_msgs.msg import MarkerArray

SESSIONS_TOOL = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "src", "tools", "sessions.py")
# The joined session 1 vs the ground truth in session 0's frame: the bound comes from the
# altimeter's noise (join_tolerance). make_survey's altimeter_noise_m (pipeline_fixture.SURVEY
# leaves the default) and the sessions' altitudes there.
ALTIMETER_NOISE_M = 0.01
ALTITUDES_M = (1.6, 1.7)



def yaw_of(q):
    return 2.0 * math.atan2(q.z, q.w)


class BackendTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp, cls.mission = make_mission("uwms_backend_")
        cls.lock = threading.Lock()
        cls.paths, cls.loops, cls.markers = {}, [], []
        cls.last_message = time.time()

        def on_path(session):
            def callback(msg):
                with cls.lock:
                    cls.paths[session] = msg
            return callback

        def on_loop(msg):
            with cls.lock:
                cls.loops.append(msg)
                cls.last_message = time.time()

        def on_markers(msg):
            with cls.lock:
                cls.markers.append(msg)

        cls.subs = [rospy.Subscriber(NS + "/paths/session_0", Path, on_path(0)),
                    rospy.Subscriber(NS + "/paths/session_1", Path, on_path(1)),
                    rospy.Subscriber(NS + "/loops", Loop, on_loop, queue_size=1000),
                    rospy.Subscriber(NS + "/loop_markers", MarkerArray, on_markers)]
        for srv in ("join_sessions", "split_session", "list_sessions", "start_session", "reload_session"):
            rospy.wait_for_service(NS + "/" + srv, timeout=60)
        cls.join = rospy.ServiceProxy(NS + "/join_sessions", JoinSessions)
        cls.split = rospy.ServiceProxy(NS + "/split_session", SplitSession)
        cls.list = rospy.ServiceProxy(NS + "/list_sessions", ListSessions)
        cls.start = rospy.ServiceProxy(NS + "/start_session", StartSession)
        cls.reload = rospy.ServiceProxy(NS + "/reload_session", ReloadSession)
        wait_for_subscribers(["/camera/image_raw", NS + "/keyframes", NS + "/loops"], "/check_backend")
        for name in ("s0", "s1"):
            subprocess.run(["rosbag", "play", "-q", "--wait-for-subscribers", "-d", "1", "-r", "4",
                            os.path.join(cls.mission, name + ".bag"),
                            "--topics"] + SENSOR_TOPICS, check=True,
                           timeout=120)
            wait_until_quiet(cls.lock, lambda: cls.last_message, 5.0)
        cls.frames = frames_by_stamp(cls.mission)  # image stamp -> (session, index) of world_gt.csv
        with open(os.path.join(cls.mission, "world_gt.csv")) as f:
            cls.world = {(int(r["session"]), int(r["index"])): (float(r["x_m"]), float(r["y_m"]), float(r["yaw_rad"]))
                         for r in csv.DictReader(f)}

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def sessions(self):
        res = self.list()
        self.assertEqual(res.status.code, Status.OK)
        return {s.session: s for s in res.sessions}

    def sessions_when(self, condition, timeout=10.0):
        """list_sessions once condition(sessions) holds, or the last answer after `timeout` seconds."""
        deadline = time.time() + timeout
        listed = self.sessions()
        while not condition(listed) and time.time() < deadline:
            time.sleep(0.1)
            listed = self.sessions()
        return listed

    @staticmethod
    def await_value(get, condition, timeout=10.0):
        """get() once condition(get()) holds, or its last value after `timeout` seconds."""
        deadline = time.time() + timeout
        value = get()
        while not condition(value) and time.time() < deadline:
            time.sleep(0.1)
            value = get()
        return value

    def path(self, session, timeout=10.0):
        deadline = time.time() + timeout
        while time.time() < deadline:
            with self.lock:
                if session in self.paths:
                    return self.paths[session]
            time.sleep(0.2)
        self.fail("no path for session %d" % session)

    def joined_error(self):
        """Largest distance of session 1's keyframes (in map 0, i.e. session 0's frame) from the
        ground truth expressed in session 0's first keyframe's frame. Poses are matched to the
        bags' images by their stamps."""
        p1 = self.path(1).poses
        ox, oy, oyaw = self.world[self.frames[self.path(0).poses[0].header.stamp.to_nsec()]]
        c, s = math.cos(oyaw), math.sin(oyaw)
        worst = 0.0
        for p in p1:
            gx, gy, _ = self.world[self.frames[p.header.stamp.to_nsec()]]
            tx, ty = c * (gx - ox) + s * (gy - oy), -s * (gx - ox) + c * (gy - oy)
            # The path gives base_link in the z-up map (camera at base_link): y is the image axes' -y.
            worst = max(worst, math.hypot(p.pose.position.x - tx, -p.pose.position.y - ty))
        return worst

    def keyframe_indexes(self, session):
        """The frame index (world_gt.csv's) of each keyframe of a session's path."""
        return [self.frames[p.header.stamp.to_nsec()][1] for p in self.path(session).poses]

    def join_tolerance(self):
        """3 x the largest rms position error that the altimeter's noise gives a keyframe of session
        1 once joined. Each measured motion, odometry or loop, is scaled by one altitude reading
        (that of its first keyframe), off by N(0, noise / altitude) relatively, so a motion of
        length d (from the ground truth) errs by d x that along itself, independently of the
        others. An optimised keyframe is at least as good as its best single chain of measurements:
        within a session the cheapest path (summed variances) from a keyframe through its motions
        and local loops. Session 1 hangs off session 0 by the link, which weighs the global loops,
        so its error is at most the largest through one of them (pi in session 0, ci in session
        1): best chain from session 0's origin to pi + the loop + best chain from ci to j in session
        1. The feature registration (about 0.5 px / sqrt(inliers), under a millimetre a motion) is
        left out. Beyond 3 x rms with probability < 0.3 % (all of it on one axis at worst)."""
        indexes = {s: self.keyframe_indexes(s) for s in (0, 1)}

        def variance(sa, ka, sb, kb):  # of the measured motion from keyframe ka of sa to kb of sb
            (xa, ya, _), (xb, yb, _) = self.world[(sa, indexes[sa][ka])], self.world[(sb, indexes[sb][kb])]
            return ((xb - xa) ** 2 + (yb - ya) ** 2) * (ALTIMETER_NOISE_M / ALTITUDES_M[sa]) ** 2

        with self.lock:
            loops = list(self.loops)

        def cheapest(session, start):  # Dijkstra over the session's motions and local loops
            n = len(indexes[session])
            edges = {k: [] for k in range(n)}
            for k in range(n - 1):
                edges[k].append((k + 1, variance(session, k, session, k + 1)))
                edges[k + 1].append((k, variance(session, k, session, k + 1)))
            for l in loops:
                if l.kind == Loop.LOCAL and l.session_a == session and max(l.keyframe_a, l.keyframe_b) < n:
                    v = variance(session, l.keyframe_a, session, l.keyframe_b)
                    edges[l.keyframe_a].append((l.keyframe_b, v))
                    edges[l.keyframe_b].append((l.keyframe_a, v))
            best, queue = {start: 0.0}, [(0.0, start)]
            while queue:
                d, k = heapq.heappop(queue)
                if d > best[k]:
                    continue
                for m, v in edges[k]:
                    if d + v < best.get(m, math.inf):
                        best[m] = d + v
                        heapq.heappush(queue, (d + v, m))
            return best

        from_origin = cheapest(0, 0)
        worst = 0.0
        for l in loops:
            if l.kind != Loop.GLOBAL or {l.session_a, l.session_b} != {0, 1}:
                continue
            pi, ci = (l.keyframe_a, l.keyframe_b) if l.session_a == 0 else (l.keyframe_b, l.keyframe_a)
            through = from_origin[pi] + variance(0, pi, 1, ci)
            worst = max(worst, through + max(cheapest(1, ci).values()))
        self.assertGreater(worst, 0.0, "no global loop between sessions 0 and 1")
        return 3.0 * math.sqrt(worst)

    def test_1_a_path_per_session_and_loops_of_both_kinds(self):
        kinds = [l.kind for l in self.loops]
        self.assertGreaterEqual(kinds.count(Loop.LOCAL), 3)
        self.assertGreaterEqual(kinds.count(Loop.GLOBAL), 3)
        listed = self.sessions()
        self.assertEqual(sorted(listed), [0, 1])
        for s in (0, 1):
            self.assertEqual(len(self.path(s).poses), listed[s].num_keyframes)
            self.assertGreater(listed[s].num_keyframes, 5)
            self.assertEqual(self.path(s).header.frame_id, "map")
            self.assertEqual(listed[s].map, s)  # not joined: automatic joining is off
        self.assertEqual(listed[1].state, listed[1].ACTIVE)
        self.assertEqual(listed[0].state, listed[0].FINISHED)
        first = self.path(1).poses[0].pose.position
        self.assertEqual((first.x, first.y), (0.0, 0.0))  # its own frame before the join

    def test_2_join_then_split(self):
        res = self.join(0, 1, 3)
        self.assertEqual(res.status.code, Status.OK, res.status.message)
        self.assertEqual(res.map, 0)
        listed = self.sessions_when(lambda listed: listed[1].map == 0)
        self.assertEqual(listed[1].map, 0)
        # The session's path is published again in map 0 once the back-end's worker has joined and
        # optimised: until it is within the tolerance (or 10 s).
        tolerance = self.join_tolerance()
        self.await_value(self.joined_error, lambda e: e < tolerance)
        error = self.joined_error()
        sys.stderr.write("joined session 1: largest error %.3f m from the ground truth, tolerance %.3f m\n"
                         % (error, tolerance))
        self.assertLess(error, tolerance)
        with self.lock:
            self.assertTrue(any(m.ns == "joins" for a in self.markers for m in a.markers), "no join marker")
        # Joining again: already in one map.
        self.assertEqual(self.join(1, 0, 0).status.code, Status.FAILED_PRECONDITION)

        res = self.split(1)
        self.assertEqual(res.status.code, Status.OK, res.status.message)
        self.assertEqual(self.sessions_when(lambda listed: listed[1].map == 1)[1].map, 1)
        origin = lambda: self.path(1).poses[0].pose.position  # noqa: E731
        self.await_value(origin, lambda p: abs(p.x) < 1e-9 and abs(p.y) < 1e-9)
        first = origin()
        self.assertAlmostEqual(first.x, 0.0, places=9)  # back in its own frame
        self.assertEqual(self.split(1).status.code, Status.FAILED_PRECONDITION)  # alone: nothing to split

    def test_3_wrong_calls_get_an_error_and_the_node_keeps_running(self):
        before = self.sessions()
        res = self.join(0, 42, 0)
        self.assertEqual(res.status.code, Status.NOT_FOUND)
        self.assertIn("42", res.status.message)
        self.assertEqual(self.join(0, 1, -3).status.code, Status.INVALID_ARGUMENT)
        self.assertEqual(self.split(-1).status.code, Status.INVALID_ARGUMENT)  # outside the ids [0, 1000000]
        self.assertEqual(self.join(0, 2 ** 31 - 1, 0).status.code, Status.INVALID_ARGUMENT)
        self.assertEqual(self.start("s1_name_taken").status.code, Status.OK)
        self.assertEqual(self.start("s1_name_taken").status.code, Status.ALREADY_EXISTS)
        # Session 2 has no keyframe yet: another start_session is refused (~max_empty_sessions 1),
        # so that calls in a loop cannot pile up empty sessions.
        res = self.start("another")
        self.assertEqual(res.status.code, Status.RESOURCE_EXHAUSTED, res.status.message)
        self.assertIn("max_empty_sessions", res.status.message)
        # A session's path topic is advertised with its first keyframe, not by start_session.
        published = [t for t, _ in rosgraph.Master("/check_backend").getSystemState()[0]]
        self.assertIn(NS + "/paths/session_1", published)
        self.assertNotIn(NS + "/paths/session_2", published)
        self.assertEqual(self.reload("yesterday").status.code, Status.FAILED_PRECONDITION)  # no store in this test
        # The same answer through sessions.py (its argument checks: test/python/test_sessions.py).
        tool = subprocess.run(["/usr/bin/python3", SESSIONS_TOOL, "--ns", NS, "reload", "yesterday"],
                              capture_output=True, text=True, timeout=60)
        self.assertEqual(tool.returncode, 3, tool.stderr)  # refused: non-zero, the code and message printed
        self.assertIn("reload_session 'yesterday' -> FAILED_PRECONDITION: no session store", tool.stdout)
        after = self.sessions()
        self.assertEqual(len(after), len(before) + 1)  # only the good start_session changed anything
        for s in before:
            self.assertEqual((after[s].map, after[s].num_keyframes), (before[s].map, before[s].num_keyframes))
        nodes = dict(rosgraph.Master("/check_backend").getSystemState()[2]).get(NS + "/list_sessions", [])
        self.assertTrue(nodes)
        for node in nodes:
            self.assertTrue(rosnode.rosnode_ping(node, max_count=1), "%s does not answer" % node)

    def test_4_diagnostics_count_what_the_back_end_did(self):
        # The back-end publishes its status once a second: the first one that counts test_2's join
        # and split (or the last seen after 20 s).
        values = backend_values(lambda v: int(v["joins"]) >= 1 and int(v["splits"]) >= 1)
        self.assertIsNotNone(values, "no back-end status on /diagnostics")
        listed = self.sessions()
        self.assertEqual(int(values["keyframes_received"]), sum(s.num_keyframes for s in listed.values() if s.session < 2))
        self.assertGreaterEqual(int(values["joins"]), 1)  # test_2 joined
        self.assertGreaterEqual(int(values["splits"]), 1)
        self.assertEqual(values["store"], "none")


    def test_5_malformed_keyframes_and_loops_are_counted_and_change_nothing(self):
        """A keyframe of a negative session (refused by the message conversion:
        bad_messages), one far beyond its session's last (a gap over ~max_keyframe_gap: refused by
        the session manager, keyframes_refused; sent to the active session, as a finished session's
        keyframes are stale whatever their id), and loops on keyframes that never arrived (held
        in the bounded waiting list, loops_waiting, ~max_waiting_loops, in case their keyframes
        come): each counted, the sessions unchanged, the node still answering."""
        first = backend_values()
        self.assertIsNotNone(first, "no back-end status on /diagnostics")
        before = self.sessions()
        keyframes = rospy.Publisher(NS + "/keyframes", Keyframe, queue_size=10)
        loops = rospy.Publisher(NS + "/loops", Loop, queue_size=10)
        deadline = time.time() + 60  # this test subscribes to the loops too: it may connect first
        while time.time() < deadline and not connected([keyframes, loops]):
            time.sleep(0.1)
        # Sent before the back-end's connections, the malformed messages would be lost, not counted.
        self.assertTrue(connected([keyframes, loops]), "the back-end never connected to this test's publishers")
        active = [s.session for s in before.values() if s.state == SessionState.ACTIVE]
        self.assertEqual(len(active), 1, before)
        for session, keyframe in ((-5, 0), (active[0], 1000000)):
            k = Keyframe(session=session, keyframe=keyframe, altitude_m=2.0, width=240, height=180, fx=220, fy=220,
                         cx=119.5, cy=89.5, descriptor_size=128, status=Keyframe.MATCHED)
            k.header.stamp = rospy.Time.now()
            k.motion_covariance = [1e-4, 0, 0, 0, 1e-4, 0, 0, 0, 1e-4]
            keyframes.publish(k)
        for a, b in (((0, 999999), (1, 0)), ((0, 0), (77, 3))):
            loop = Loop(kind=Loop.GLOBAL, session_a=a[0], keyframe_a=a[1], session_b=b[0], keyframe_b=b[1], inliers=60)
            loop.covariance = [1e-4, 0, 0, 0, 1e-4, 0, 0, 0, 1e-4]
            loops.publish(loop)
        counters = ("bad_messages", "keyframes_refused", "loops_waiting")
        start = {c: int(first[c]) for c in counters}
        values = backend_values(lambda v: all(int(v[c]) >= start[c] + 1 + (c == "loops_waiting") for c in counters))
        self.assertEqual([int(values[c]) - start[c] for c in counters], [1, 1, 2], values)
        self.assertEqual(int(values["loops_refused"]), int(first["loops_refused"]), values)
        after = self.sessions()
        self.assertEqual(sorted(after), sorted(before))
        for s in before:
            self.assertEqual((after[s].map, after[s].num_keyframes, after[s].num_loops),
                             (before[s].map, before[s].num_keyframes, before[s].num_loops))


if __name__ == "__main__":
    rospy.init_node("check_backend")
    rostest.rosrun("uw_multislam", "check_backend", BackendTest)
