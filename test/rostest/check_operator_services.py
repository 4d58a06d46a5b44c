#!/usr/bin/python3
"""rostest: the back-end's operator services add_link, optimise, detect_loops
(item 3) and history (item 5), called right and called wrong, on back-end nodes this test starts with their own stores.

Session 0 (8 keyframes) and session 1 (5), each driven straight along x at 0.5 m per keyframe;
optimise_every is 100, so a loop inside a map waits for the operator's optimise. Every wrong call
gets its status code and a message and changes nothing (list_sessions identical); a local link
waits, optimise solves it (the diagnostics count one optimisation), a second optimise finds
nothing waiting; one global link lets join_sessions with min_loops 1 join the two maps, and the
store holds both links after a clean shutdown.

detect_loops: the fixture mission's two sessions, each run alone by offline_slam into its own store
and merged without loops (merge_stores --no-loops): two stored maps. The service finds the global
loops between them and the back-end joins the maps by its rule (K loops); a second call finds only
loops it holds already; wrong calls are refused with nothing changed.
"""
import hashlib
import math
import os
import shutil
import signal
import sqlite3
import subprocess
import tempfile
import threading
import time
import unittest

import rospy
import rostest
from geometry_msgs.msg import Pose2D
from pipeline_fixture import DiagnosticsWatch, await_condition, connected, make_mission, synthetic_keyframe, tool
from uw_multislam.msg import Keyframe, Loop, SessionState, Status
from nav_msgs.msg import Path
from uw_multislam.srv import AddLink, DeleteSession, DetectLoops, FinishSession, History, JoinSessions, ListSessions, Optimise, SetMode, SplitSession

NS = "/operator_test"
SESSIONS_TOOL = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "src", "tools", "sessions.py")
FEATURES = 50
KEYFRAMES = {0: 8, 1: 5}
COV = [1e-4, 0, 0, 0, 1e-4, 0, 0, 0, 1e-4]


class OperatorServicesTest(unittest.TestCase):
    def setUp(self):
        self.tmp = tempfile.mkdtemp(prefix="uwms_operator_")
        self.db = os.path.join(self.tmp, "store.db")
        self.lock = threading.RLock()  # await_condition holds it while optimisations() takes it
        self.diagnostics = DiagnosticsWatch(("backend",), self.lock)
        self.node = None

    def start_backend(self, db, backend_params=None, name="backend_node", args=()):
        if backend_params:
            rospy.set_param(NS + "/slam/backend", backend_params)
        self.node = subprocess.Popen([tool("backend_node"), "__ns:=" + NS, "__name:=" + name,
                                      "_store_path:=" + db, "_diagnostic_period:=0.2", *args],
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        self.lines = []
        threading.Thread(target=lambda: self.lines.extend(self.node.stdout), daemon=True).start()

    def tearDown(self):
        self.diagnostics.unregister()
        if self.node is not None and self.node.poll() is None:
            self.node.send_signal(signal.SIGINT)  # a clean exit unregisters its topics from the master
            try:
                self.node.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.node.kill()
                self.node.wait()
        if rospy.has_param(NS + "/slam"):
            rospy.delete_param(NS + "/slam")
        shutil.rmtree(self.tmp, ignore_errors=True)

    def sessions(self):
        res = rospy.ServiceProxy(NS + "/list_sessions", ListSessions)()
        self.assertEqual(res.status.code, Status.OK)
        return {s.session: (s.state, s.map, s.num_keyframes, s.num_loops) for s in res.sessions}

    def optimisations(self):
        return int(self.diagnostics.get().get("optimisations", -1))

    def stop_backend(self):
        self.node.send_signal(signal.SIGINT)
        self.node.wait(timeout=60)
        self.assertEqual(self.node.returncode, 0, "".join(self.lines)[-3000:])

    def feed(self, keyframes, loops=()):
        """Publishes {session: n} keyframes and the loops, with a publisher of this call's own (a
        publisher kept from an earlier back-end node could count its dead connection)."""
        kf_pub = rospy.Publisher(NS + "/keyframes", Keyframe, queue_size=100)
        loop_pub = rospy.Publisher(NS + "/loops", Loop, queue_size=100)
        try:
            await_condition(self.lock, lambda: connected([kf_pub, loop_pub]), 30, "the back-end's subscriptions")
            for session, n in keyframes.items():
                for k in range(n):
                    kf_pub.publish(synthetic_keyframe(session, k, FEATURES))
            for loop in loops:
                loop_pub.publish(loop)
            deadline = time.time() + 60
            while time.time() < deadline and any(self.sessions().get(s, (0, 0, 0, 0))[2] != n
                                                 for s, n in keyframes.items()):
                time.sleep(0.1)
        finally:
            kf_pub.unregister()
            loop_pub.unregister()

    def link(self, a, ka, b, kb, pose=(0.0, 1.0, 0.0), covariance=COV, inliers=0, find=False):
        return rospy.ServiceProxy(NS + "/add_link", AddLink)(a, ka, b, kb, Pose2D(*pose), covariance, inliers, find)

    def test_add_link_and_optimise_called_right_and_wrong(self):
        self.start_backend(self.db, {"optimise_every": 100, "intra_loop_gate": False})
        for name in ("list_sessions", "add_link", "optimise", "join_sessions"):
            rospy.wait_for_service(NS + "/" + name, timeout=60)
        self.feed(KEYFRAMES)
        before = self.sessions()
        self.assertEqual([v[2] for v in before.values()], list(KEYFRAMES.values()), before)
        self.assertEqual([v[1] for v in before.values()], [0, 1])  # two maps

        optimise = rospy.ServiceProxy(NS + "/optimise", Optimise)
        nothing = optimise()
        self.assertEqual((nothing.status.code, nothing.maps), (Status.OK, 0), nothing.status.message)

        wrong = [((0, 2, 42, 2), {}, Status.NOT_FOUND), ((0, 2, 1, 99), {}, Status.NOT_FOUND),
                 ((-1, 2, 1, 2), {}, Status.INVALID_ARGUMENT), ((1, 2, 1, 2), {}, Status.INVALID_ARGUMENT),
                 ((0, 2, 1, 2), {"pose": (math.nan, 0.0, 0.0)}, Status.INVALID_ARGUMENT),
                 ((0, 2, 1, 2), {"covariance": [0.0] * 9}, Status.INVALID_ARGUMENT),
                 ((0, 2, 1, 2), {"covariance": [1e-4, 5e-5, 0, 0, 1e-4, 0, 0, 0, 1e-4]}, Status.INVALID_ARGUMENT),
                 ((0, 2, 1, 2), {"inliers": -3}, Status.INVALID_ARGUMENT),
                 # Out of range, named as such: a yaw Pose2 would have wrapped to 0.577 rad, and more
                 # inliers than a keyframe has features.
                 ((0, 2, 1, 2), {"pose": (0.0, 1.0, 1e9)}, Status.INVALID_ARGUMENT),
                 ((0, 2, 1, 2), {"inliers": 2 ** 31 - 1}, Status.INVALID_ARGUMENT)]
        reasons = {(0.0, 1.0, 1e9): "outside [-pi, pi]", 2 ** 31 - 1: "inliers is more than"}
        for args, kwargs, code in wrong:
            res = self.link(*args, **kwargs)
            self.assertEqual(res.status.code, code, "%s %s: %s" % (args, kwargs, res.status.message))
            self.assertTrue(res.status.message, (args, kwargs))
            for value in kwargs.values():
                if isinstance(value, (tuple, int)) and value in reasons:
                    self.assertIn(reasons[value], res.status.message)
        self.assertEqual(self.sessions(), before, "a refused add_link changed the sessions")

        # A local link 0.3 m longer than the odometry: it waits (1 of 100), optimise solves it.
        await_condition(self.lock, lambda: self.optimisations() >= 0, 30, "the back-end's diagnostics")
        solved = self.optimisations()
        res = self.link(1, 0, 1, 4, pose=(2.3, 0.0, 0.0))
        self.assertEqual(res.status.code, Status.OK, res.status.message)
        self.assertEqual(self.sessions()[1][3], 1)
        due = optimise()
        self.assertEqual((due.status.code, due.maps), (Status.OK, 1), due.status.message)
        await_condition(self.lock, lambda: self.optimisations() == solved + 1, 30, "the optimisation",
                        lambda: ": %s" % self.diagnostics.get())
        again = optimise()
        self.assertEqual((again.status.code, again.maps), (Status.OK, 0), again.status.message)

        # One global link, then an operator's join through it.
        res = self.link(0, 2, 1, 2)
        self.assertEqual(res.status.code, Status.OK, res.status.message)
        join = rospy.ServiceProxy(NS + "/join_sessions", JoinSessions)(0, 1, 1)
        self.assertEqual(join.status.code, Status.OK, join.status.message)
        after = self.sessions()
        self.assertEqual(after[1][1], 0, after)
        self.assertEqual((after[0][3], after[1][3]), (1, 2), after)

        # The audit trail: both links and the join, each with the service as cause;
        # splitting the joined session off again undoes that join and says so.
        history = rospy.ServiceProxy(NS + "/history", History)
        res = history(0)
        self.assertEqual(res.status.code, Status.OK, res.status.message)
        self.assertEqual([(e.id, e.kind, e.cause, e.sessions, e.loops) for e in res.entries],
                         [(1, "link", "service", "1", "1:0>1:4"), (2, "link", "service", "0,1", "0:2>1:2"),
                          (3, "join", "service", "0+1", "0:2>1:2")], res.entries)
        split = rospy.ServiceProxy(NS + "/split_session", SplitSession)(1)
        self.assertEqual(split.status.code, Status.OK, split.status.message)
        res = history(1)
        self.assertEqual([(e.id, e.kind, e.cause, e.sessions) for e in res.entries], [(4, "split", "service", "1+0")])
        self.assertIn("undoes join #3", res.entries[0].message)
        wrong = history(-1)
        self.assertEqual((wrong.status.code, len(wrong.entries)), (Status.INVALID_ARGUMENT, 0), wrong.status.message)
        join = rospy.ServiceProxy(NS + "/join_sessions", JoinSessions)(0, 1, 1)  # and back, for what follows
        self.assertEqual(join.status.code, Status.OK, join.status.message)
        tool_says = subprocess.run([SESSIONS_TOOL, "--ns", NS, "history", "2"], capture_output=True, text=True,
                                   timeout=60)
        self.assertEqual(tool_says.returncode, 0, tool_says)
        lines = tool_says.stdout.splitlines()
        self.assertEqual(lines[0], "history -> OK, 2 entries", tool_says.stdout)
        self.assertTrue(lines[1].startswith("  #4 ") and "split" in lines[1] and "undoes join #3" in lines[1], lines)
        self.assertTrue(lines[2].startswith("  #5 ") and "join" in lines[2] and "loops 0:2>1:2" in lines[2], lines)

        # The same services through sessions.py (its argument checks: test/python/test_sessions.py).
        tool_says = subprocess.run([SESSIONS_TOOL, "--ns", NS, "optimise"], capture_output=True, text=True, timeout=60)
        self.assertEqual((tool_says.returncode, tool_says.stdout.strip()), (0, "optimise -> OK, 0 maps due"), tool_says)
        tool_says = subprocess.run([SESSIONS_TOOL, "--ns", NS, "link", "0", "2", "7", "2", "0", "1", "0", "0.01", "0.01"],
                                   capture_output=True, text=True, timeout=60)
        self.assertEqual(tool_says.returncode, 3, tool_says)  # refused: non-zero
        self.assertTrue(tool_says.stdout.startswith("add_link 0:2 -> 7:2 -> NOT_FOUND: no session 7"), tool_says.stdout)

        self.stop_backend()
        with sqlite3.connect(self.db) as c:
            stored = c.execute("SELECT keyframe_a, keyframe_b, kind FROM loops ORDER BY id").fetchall()
            trail = c.execute("SELECT id, kind, cause FROM history ORDER BY id").fetchall()
        self.assertEqual([tuple(r) for r in stored], [(0, 4, "local"), (2, 2, "global")])
        self.assertEqual([tuple(r) for r in trail], [(1, "link", "service"), (2, "link", "service"),
                                                     (3, "join", "service"), (4, "split", "service"),
                                                     (5, "join", "service")])

    def test_detect_loops_joins_two_stored_maps(self):
        tmp, mission = make_mission("uwms_detect_")
        try:
            stores = []
            for name in ("s0", "s1"):
                stores.append(os.path.join(tmp, name + ".db"))
                subprocess.run([tool("offline_slam"), "--session", os.path.join(mission, name), "--db", stores[-1],
                                "--out", os.path.join(tmp, "run_" + name), "--quiet"], check=True, timeout=300)
            merged = os.path.join(tmp, "merged.db")
            subprocess.run([tool("merge_stores"), merged] + stores + ["--no-loops", "--quiet"], check=True, timeout=300)
            self.start_backend(merged)
            rospy.wait_for_service(NS + "/detect_loops", timeout=60)
            detect = rospy.ServiceProxy(NS + "/detect_loops", DetectLoops)
            before = self.sessions()
            self.assertEqual([(s, v[0], v[1]) for s, v in before.items()],
                             [(0, SessionState.UNLOADED, 0), (1, SessionState.UNLOADED, 1)], before)
            loops_before = before[0][3] + before[1][3]
            for sessions, code in (([], Status.INVALID_ARGUMENT), ([0], Status.INVALID_ARGUMENT),
                                   ([1, 1], Status.INVALID_ARGUMENT), ([0, 5], Status.NOT_FOUND)):
                res = detect(sessions)
                self.assertEqual(res.status.code, code, "%s: %s" % (sessions, res.status.message))
                self.assertTrue(res.status.message)
                self.assertEqual(res.queries, 0)
            self.assertEqual(self.sessions(), before)

            # add_link "find it" first: half a lap apart in session 0 nothing is verified; across the
            # sessions the first pair that overlaps is measured and added (a loop like the others).
            far = self.link(0, 0, 0, before[0][2] // 2, find=True)
            self.assertEqual(far.status.code, Status.FAILED_PRECONDITION, far.status.message)
            self.assertIn("no motion verified", far.status.message)
            self.assertEqual(self.sessions(), before)
            found = next(((i, j, r) for i in range(before[0][2]) for j in range(before[1][2])
                          for r in [self.link(0, i, 1, j, find=True)] if r.status.code == Status.OK), None)
            self.assertIsNotNone(found, "no pair of keyframes across the sessions was verified")
            print("add_link find: 0:%d -> 1:%d, pose (%.3f, %.3f, %.4f), %d inliers" % (
                found[0], found[1], found[2].pose.x, found[2].pose.y, found[2].pose.theta, found[2].inliers), flush=True)
            self.assertGreaterEqual(found[2].inliers, 20)  # loops.global.min_inliers
            # The first pair tried, both sessions' first keyframes, overlaps: SURVEY starts s1 at
            # (6.5, 5.5) heading pi/2 and s0 at (6.0, 5.0) heading 0, so b in a is (0.5, 0.5, pi/2).
            self.assertEqual(found[:2], (0, 0))
            pose = found[2].pose
            self.assertLess(math.hypot(pose.x - 0.5, pose.y - 0.5), 0.02, pose)
            self.assertLess(abs(pose.theta - math.pi / 2), 0.01, pose)
            self.assertEqual(self.sessions()[1][3], before[1][3] + 1)
            loops_before += 2

            res = detect([0, 1])
            self.assertEqual(res.status.code, Status.OK, res.status.message)
            print("detect_loops [0, 1]: %d queried, %d candidates, %d found, %d held, %d accepted, %d refused, %d joins"
                  % (res.queries, res.candidates, res.found, res.already_held, res.accepted, res.refused, res.joins),
                  flush=True)
            self.assertEqual(res.queries, before[1][2])  # every keyframe of session 1
            self.assertLessEqual(res.already_held, 1)  # the found link, when the hash search proposes it too
            self.assertGreaterEqual(res.accepted, 5)  # the back-end's K: enough for its join rule
            self.assertEqual(res.joins, 1)
            after = self.sessions()
            self.assertEqual(after[1][1], 0, after)
            self.assertEqual(after[0][3] + after[1][3], loops_before + 2 * res.accepted, after)
            again = subprocess.run([SESSIONS_TOOL, "--ns", NS, "detect", "0", "1"], capture_output=True, text=True,
                                   timeout=120)  # through sessions.py: only loops held already
            self.assertEqual(again.returncode, 0, again)
            self.assertIn("detect_loops 0 1 -> OK; %d keyframes queried, %d candidates, %d loops (%d held already), "
                          "0 accepted, 0 refused, 0 joins" % (res.queries, res.candidates, res.found, res.found),
                          again.stdout)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)

    def test_delete_session_called_right_and_wrong(self):
        """delete_session: refused with nothing changed while the session records,
        shares its map, without confirm, in localisation mode, for an unknown name; then deleted from
        memory and store (its loops too), its path emptied, recorded in the history."""
        self.start_backend(self.db, {"intra_loop_gate": False})
        for name in ("list_sessions", "delete_session", "finish_session", "history", "split_session"):
            rospy.wait_for_service(NS + "/" + name, timeout=60)
        self.feed(KEYFRAMES)
        delete = rospy.ServiceProxy(NS + "/delete_session", DeleteSession)
        paths = []
        path_sub = rospy.Subscriber(NS + "/paths/session_1", Path, lambda m: paths.append(len(m.poses)), queue_size=10)
        await_condition(self.lock, lambda: paths and paths[-1] == KEYFRAMES[1], 30, "session 1's path")

        def refused(name, confirm, code, why):
            before = self.sessions()
            res = delete(name, confirm)
            self.assertEqual(res.status.code, code, "%s %s: %s" % (name, confirm, res.status.message))
            self.assertIn(why, res.status.message)
            self.assertEqual(self.sessions(), before, "a refused delete_session changed the sessions")

        refused("1", True, Status.FAILED_PRECONDITION, "finish_session first")
        self.assertEqual(rospy.ServiceProxy(NS + "/finish_session", FinishSession)().status.code, Status.OK)
        self.assertEqual(self.link(0, 2, 1, 2).status.code, Status.OK)
        self.assertEqual(rospy.ServiceProxy(NS + "/join_sessions", JoinSessions)(0, 1, 1).status.code, Status.OK)
        refused("1", True, Status.FAILED_PRECONDITION, "split_session it off first")
        self.assertEqual(rospy.ServiceProxy(NS + "/split_session", SplitSession)(1).status.code, Status.OK)
        refused("1", False, Status.FAILED_PRECONDITION, "(5 keyframes, 1 loops) from the store for good: call again "
                                                        "with confirm true")
        refused("session_9", True, Status.NOT_FOUND, "session_9")
        set_mode = rospy.ServiceProxy(NS + "/set_mode", SetMode)
        self.assertEqual(set_mode("localisation").status.code, Status.OK)
        refused("1", True, Status.FAILED_PRECONDITION, "localisation mode")
        self.assertEqual(set_mode("mapping").status.code, Status.OK)
        tool_says = subprocess.run([SESSIONS_TOOL, "--ns", NS, "delete", "1"], capture_output=True, text=True,
                                   timeout=60)
        self.assertEqual(tool_says.returncode, 3, tool_says)  # refused: non-zero
        self.assertTrue(tool_says.stdout.startswith("delete_session '1' -> FAILED_PRECONDITION: delete_session removes "
                                                    "session 1 ('session_1')"), tool_says.stdout)

        res = delete("session_1", True)
        self.assertEqual((res.status.code, res.session), (Status.OK, 1), res.status.message)
        self.assertEqual(sorted(self.sessions()), [0])
        self.assertEqual(self.sessions()[0][3], 0)  # the link went with it
        await_condition(self.lock, lambda: self.diagnostics.get().get("sessions_deleted") == 1, 30, "sessions_deleted")
        await_condition(self.lock, lambda: paths[-1] == 0, 30, "the emptied path", lambda: ": %s" % paths)
        path_sub.unregister()
        entries = rospy.ServiceProxy(NS + "/history", History)(0).entries
        self.assertEqual([(e.kind, e.cause, e.sessions) for e in entries],
                         [("link", "service", "0,1"), ("join", "service", "0+1"), ("split", "service", "1+0"),
                          ("mode", "service", ""), ("delete", "service", "1")])
        again = delete("1", True)
        self.assertEqual(again.status.code, Status.NOT_FOUND, again.status.message)
        self.stop_backend()
        with sqlite3.connect(self.db) as c:
            self.assertEqual(c.execute("SELECT name FROM sessions").fetchall(), [("session_0",)])
            self.assertEqual(c.execute("SELECT COUNT(*) FROM loops").fetchone()[0], 0)
            self.assertEqual(c.execute("SELECT COUNT(*) FROM keyframes").fetchone()[0], KEYFRAMES[0])
            self.assertEqual(c.execute("SELECT kind FROM history ORDER BY id").fetchall(),
                             [("link",), ("join",), ("split",), ("mode",), ("delete",)])

    def test_localisation_mode_leaves_the_store_byte_identical(self):
        """set_mode (the store byte-identical by md5)."""
        self.start_backend(self.db, name="mapping_node")
        rospy.wait_for_service(NS + "/list_sessions", timeout=60)
        self.feed({0: 8})
        self.assertEqual(self.sessions()[0][2], 8)
        self.stop_backend()
        stored = md5(self.db)

        self.start_backend(self.db, name="switched_node")
        for name in ("set_mode", "join_sessions", "add_link", "optimise", "detect_loops"):
            rospy.wait_for_service(NS + "/" + name, timeout=60)
        set_mode = rospy.ServiceProxy(NS + "/set_mode", SetMode)
        res = set_mode("survey")
        self.assertEqual((res.status.code, res.mode), (Status.INVALID_ARGUMENT, "mapping"), res.status.message)
        tool_says = subprocess.run([SESSIONS_TOOL, "--ns", NS, "mode", "localisation"], capture_output=True, text=True,
                                   timeout=60)
        self.assertEqual((tool_says.returncode, tool_says.stdout.strip()),
                         (0, "set_mode localisation -> OK, localisation mode"), tool_says)
        res = set_mode("localization")  # again, in the ROS world's spelling: OK, said
        self.assertEqual((res.status.code, res.mode), (Status.OK, "localisation"), res.status.message)
        await_condition(self.lock, lambda: self.diagnostics.get().get("mode") == "localisation", 30, "mode on /diagnostics")
        local = Loop(kind=Loop.LOCAL, session_a=1, keyframe_a=0, session_b=1, keyframe_b=4, pose=Pose2D(2.0, 0, 0),
                     covariance=COV, inliers=80)
        across = Loop(kind=Loop.GLOBAL, session_a=0, keyframe_a=2, session_b=1, keyframe_b=2,
                      pose=Pose2D(0, 1.0, 0), covariance=COV, inliers=80)
        self.feed({1: 5}, [local, across])
        await_condition(self.lock, lambda: self.sessions()[1][3] == 2, 30, "the two loops")
        tracked = self.sessions()
        self.assertEqual((tracked[1][2], tracked[1][1]), (5, 1), tracked)  # tracked, alone in its map
        refused = [rospy.ServiceProxy(NS + "/join_sessions", JoinSessions)(0, 1, 1).status,
                   self.link(0, 3, 1, 3).status, rospy.ServiceProxy(NS + "/optimise", Optimise)().status,
                   rospy.ServiceProxy(NS + "/detect_loops", DetectLoops)([0, 1]).status]
        for status in refused:
            self.assertEqual(status.code, Status.FAILED_PRECONDITION, status.message)
            self.assertIn("localisation mode", status.message)
        self.assertEqual(self.sessions(), tracked)
        self.stop_backend()
        self.assertEqual(md5(self.db), stored, "localisation mode changed the store")

        # ~mode at start: nothing written from the start; the localisation session was never stored.
        self.start_backend(self.db, name="localising_node", args=["_mode:=localisation"])
        rospy.wait_for_service(NS + "/list_sessions", timeout=60)
        await_condition(self.lock, lambda: self.diagnostics.get().get("mode") == "localisation", 30, "mode on /diagnostics")
        self.assertEqual(sorted(self.sessions()), [0])
        self.stop_backend()
        self.assertEqual(md5(self.db), stored, "a start in localisation mode changed the store")


def md5(path):
    with open(path, "rb") as f:
        return hashlib.md5(f.read()).hexdigest()


if __name__ == "__main__":
    rospy.init_node("check_operator_services")
    rostest.rosrun("uw_multislam", "check_operator_services", OperatorServicesTest)
