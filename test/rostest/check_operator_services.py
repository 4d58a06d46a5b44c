#!/usr/bin/python3
"""rostest: the back-end's operator services add_link and optimise (issue 16, item 4), called right
and called wrong, on a back-end node this test starts with its own store and feeds directly.

Session 0 (8 keyframes) and session 1 (5), each driven straight along x at 0.5 m per keyframe;
optimise_every is 100, so a loop inside a map waits for the operator's optimise. Every wrong call
gets its status code and a message and changes nothing (list_sessions identical); a local link
waits, optimise solves it (the diagnostics count one optimisation), a second optimise finds
nothing waiting; one global link lets join_sessions with min_loops 1 join the two maps, and the
store holds both links after a clean shutdown.
"""
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
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Pose2D
from pipeline_fixture import await_condition, connected, diagnostic_values, synthetic_keyframe, tool
from uw_multislam.msg import Keyframe, Status
from uw_multislam.srv import AddLink, JoinSessions, ListSessions, Optimise

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
        self.status = {}
        self.diag_sub = rospy.Subscriber("/diagnostics", DiagnosticArray, self.on_diagnostics, queue_size=100)
        rospy.set_param(NS + "/slam/backend", {"optimise_every": 100, "intra_loop_gate": False})
        self.node = subprocess.Popen([tool("backend_node"), "__ns:=" + NS, "__name:=backend_node",
                                      "_store_path:=" + self.db, "_diagnostic_period:=0.2"],
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        self.lines = []
        threading.Thread(target=lambda: self.lines.extend(self.node.stdout), daemon=True).start()

    def tearDown(self):
        self.diag_sub.unregister()
        if self.node.poll() is None:
            self.node.kill()
            self.node.wait()
        rospy.delete_param(NS + "/slam")
        shutil.rmtree(self.tmp, ignore_errors=True)

    def on_diagnostics(self, msg):
        for s in msg.status:
            if s.name.endswith(": backend"):
                with self.lock:
                    self.status = diagnostic_values(s)

    def sessions(self):
        res = rospy.ServiceProxy(NS + "/list_sessions", ListSessions)()
        self.assertEqual(res.status.code, Status.OK)
        return {s.session: (s.state, s.map, s.num_keyframes, s.num_loops) for s in res.sessions}

    def optimisations(self):
        with self.lock:
            return int(self.status.get("optimisations", -1))

    def link(self, a, ka, b, kb, pose=(0.0, 1.0, 0.0), covariance=COV, inliers=0):
        return rospy.ServiceProxy(NS + "/add_link", AddLink)(a, ka, b, kb, Pose2D(*pose), covariance, inliers)

    def test_add_link_and_optimise_called_right_and_wrong(self):
        for name in ("list_sessions", "add_link", "optimise", "join_sessions"):
            rospy.wait_for_service(NS + "/" + name, timeout=60)
        kf_pub = rospy.Publisher(NS + "/keyframes", Keyframe, queue_size=100)
        await_condition(self.lock, lambda: connected([kf_pub]), 30, "the back-end's keyframe subscription")
        for session, n in KEYFRAMES.items():
            for k in range(n):
                kf_pub.publish(synthetic_keyframe(session, k, FEATURES))
        deadline = time.time() + 60
        while time.time() < deadline and [v[2] for v in self.sessions().values()] != list(KEYFRAMES.values()):
            time.sleep(0.1)
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
                 ((0, 2, 1, 2), {"inliers": -3}, Status.INVALID_ARGUMENT)]
        for args, kwargs, code in wrong:
            res = self.link(*args, **kwargs)
            self.assertEqual(res.status.code, code, "%s %s: %s" % (args, kwargs, res.status.message))
            self.assertTrue(res.status.message, (args, kwargs))
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
                        lambda: ": %s" % self.status)
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

        # The same services through sessions.py (its argument checks: test/python/test_sessions.py).
        tool_says = subprocess.run([SESSIONS_TOOL, "--ns", NS, "optimise"], capture_output=True, text=True, timeout=60)
        self.assertEqual((tool_says.returncode, tool_says.stdout.strip()), (0, "optimise -> OK, 0 maps due"), tool_says)
        tool_says = subprocess.run([SESSIONS_TOOL, "--ns", NS, "link", "0", "2", "7", "2", "0", "1", "0", "0.01", "0.01"],
                                   capture_output=True, text=True, timeout=60)
        self.assertEqual(tool_says.returncode, 0, tool_says)
        self.assertTrue(tool_says.stdout.startswith("add_link 0:2 -> 7:2 -> NOT_FOUND: no session 7"), tool_says.stdout)

        self.node.send_signal(signal.SIGINT)
        self.node.wait(timeout=60)
        self.assertEqual(self.node.returncode, 0, "".join(self.lines)[-3000:])
        with sqlite3.connect(self.db) as c:
            stored = c.execute("SELECT keyframe_a, keyframe_b, kind FROM loops ORDER BY id").fetchall()
        self.assertEqual([tuple(r) for r in stored], [(0, 4, "local"), (2, 2, "global")])


if __name__ == "__main__":
    rospy.init_node("check_operator_services")
    rostest.rosrun("uw_multislam", "check_operator_services", OperatorServicesTest)
