#!/usr/bin/python3
"""rostest: the session store through ROS (issue 8).

1. Session 0 is replayed; after 8 keyframes the back-end process gets SIGKILL mid-replay and
   roslaunch respawns it. It reopens the store: session 0 is there (UNLOADED) with every keyframe
   the odometry published before the kill (at most the one in flight may be missing).
2. reload_session brings session 0 back into the loop search; the second session's bag is played
   and global loops are found against the reloaded session.
3. Wrong reloads: an unknown name (NOT_FOUND) and a second reload (ALREADY_EXISTS).
"""
import os
import shutil
import signal
import subprocess
import tempfile
import threading
import time
import unittest

import rosgraph
import roslib.packages
import rospy
import rostest
from uw_multislam.msg import Keyframe, Loop, SessionState, Status
from uw_multislam.srv import ListSessions, ReloadSession

SURVEY = """
seed: 5
world: {width_m: 12, height_m: 10, metres_per_px: 0.008, featureless_fraction: 0.0}
sessions:
  - name: s0
    camera: {image_width: 240, image_height: 180, fx: 220, fy: 220, cx: 119.5, cy: 89.5}
    mission: {pattern: loop, start_m: [6.0, 5.0], length_m: 3.5, width_m: 2.5, laps: 1.3, speed_m_s: 0.35,
              frame_period_s: 1.0, altitude_m: 1.6, start_time_s: 0}
  - name: s1
    camera: {image_width: 240, image_height: 180, fx: 220, fy: 220, cx: 119.5, cy: 89.5}
    mission: {pattern: loop, start_m: [6.5, 5.5], heading_rad: 1.5708, length_m: 2.5, width_m: 3.0, laps: 1.0,
              speed_m_s: 0.35, frame_period_s: 1.0, altitude_m: 1.7, start_time_s: 1000}
"""
NS = "/uw_multislam"


def tool(name):
    found = roslib.packages.find_node("uw_multislam", name)
    if not found:
        raise RuntimeError("uw_multislam/%s not built" % name)
    return found[0]


def backend_pid():
    out = subprocess.run(["pgrep", "-f", "backend_node.*__name:=backend"], capture_output=True, text=True).stdout
    pids = [int(p) for p in out.split()]
    return pids[0] if pids else None


class StoreTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="uwms_store_")
        with open(os.path.join(cls.tmp, "survey.yaml"), "w") as f:
            f.write(SURVEY)
        cls.mission = os.path.join(cls.tmp, "mission")
        subprocess.run([tool("make_survey"), "--config", os.path.join(cls.tmp, "survey.yaml"), "--out", cls.mission,
                        "--quiet"], check=True, timeout=120)
        cls.lock = threading.Lock()
        cls.keyframes, cls.loops = [], []
        cls.last = time.time()

        def keep(store):
            def cb(msg):
                with cls.lock:
                    store.append(msg)
                    cls.last = time.time()
            return cb
        cls.subs = [rospy.Subscriber(NS + "/keyframes", Keyframe, keep(cls.keyframes), queue_size=1000),
                    rospy.Subscriber(NS + "/loops", Loop, keep(cls.loops), queue_size=1000)]
        cls.list = rospy.ServiceProxy(NS + "/list_sessions", ListSessions, persistent=False)
        cls.reload = rospy.ServiceProxy(NS + "/reload_session", ReloadSession, persistent=False)
        rospy.wait_for_service(NS + "/list_sessions", timeout=60)
        master = rosgraph.Master("/check_store")
        deadline = time.time() + 60
        while time.time() < deadline:
            subscribed = {t: n for t, n in master.getSystemState()[1]}
            if all(any(n != rospy.get_name() for n in subscribed.get(t, []))
                   for t in ("/camera/image_raw", NS + "/keyframes", NS + "/loops")):
                break
            time.sleep(0.5)
        time.sleep(2.0)

        # 1. Replay session 0 and kill the back-end after 8 keyframes.
        play = subprocess.Popen(["rosbag", "play", "-q", "-r", "3", os.path.join(cls.mission, "s0.bag"), "--topics",
                                 "/camera/image_raw", "/camera/camera_info", "/altitude"])
        cls.killed_after = None
        deadline = time.time() + 120
        while time.time() < deadline and cls.killed_after is None:
            with cls.lock:
                n = len(cls.keyframes)
            if n >= 8:
                pid = backend_pid()
                if pid:
                    time.sleep(0.2)  # the keyframes published so far reach the back-end
                    with cls.lock:
                        cls.killed_after = len(cls.keyframes)
                    os.kill(pid, signal.SIGKILL)
            time.sleep(0.05)
        play.wait(timeout=120)
        time.sleep(3.0)
        rospy.wait_for_service(NS + "/list_sessions", timeout=60)  # respawned
        cls.after_restart = cls.sessions()

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    @classmethod
    def sessions(cls):
        deadline = time.time() + 30
        while True:
            try:
                res = cls.list()
                return {s.session: s for s in res.sessions}
            except (rospy.ServiceException, rospy.ROSException):
                if time.time() > deadline:
                    raise
                time.sleep(0.5)

    def test_1_killed_session_is_back_with_every_keyframe(self):
        self.assertIsNotNone(self.killed_after, "the back-end was never killed")
        self.assertIn(0, self.after_restart)
        stored = self.after_restart[0]
        self.assertEqual(stored.state, SessionState.UNLOADED, str(self.after_restart))
        published_session0 = len([k for k in self.keyframes[:self.killed_after] if k.session == 0])
        sys_msg = "published before the kill: %d, stored: %d" % (published_session0, stored.num_keyframes)
        import sys
        sys.stderr.write(sys_msg + "\n")
        self.assertGreaterEqual(stored.num_keyframes, published_session0 - 1, sys_msg)  # at most one in flight
        self.assertGreaterEqual(stored.num_keyframes, 7)

    def test_2_reload_then_global_loops_against_it(self):
        res = self.reload("0")
        self.assertEqual(res.status.code, Status.OK, res.status.message)
        self.assertEqual(res.session, 0)
        self.assertEqual(self.sessions()[0].state, SessionState.FINISHED)
        with self.lock:
            loops_before = len(self.loops)
        subprocess.run(["rosbag", "play", "-q", "-d", "1", "-r", "4", os.path.join(self.mission, "s1.bag"),
                        "--topics", "/camera/image_raw", "/camera/camera_info", "/altitude"], check=True, timeout=120)
        deadline = time.time() + 60
        while time.time() < deadline:
            with self.lock:
                if time.time() - self.last > 5.0:
                    break
            time.sleep(0.2)
        with self.lock:
            against = [l for l in self.loops[loops_before:] if l.kind == Loop.GLOBAL and l.session_a == 0]
        self.assertGreaterEqual(len(against), 3, "global loops against the reloaded session")

    def test_3_wrong_reloads(self):
        res = self.reload("no_such_session")
        self.assertEqual(res.status.code, Status.NOT_FOUND)
        self.assertIn("no_such_session", res.status.message)
        self.reload("0")
        self.assertEqual(self.reload("0").status.code, Status.ALREADY_EXISTS)


if __name__ == "__main__":
    rospy.init_node("check_store")
    rostest.rosrun("uw_multislam", "check_store", StoreTest)
