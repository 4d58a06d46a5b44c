#!/usr/bin/python3
"""rostest: record_run.py writes as it goes, so a recorder killed with SIGKILL keeps its rows.

The test starts record_run.py (no folders: ROS ids as they are), publishes as the back-end would
session 0's keyframes 0-5, two loops and the session's latched path, waits until the rows are in
the recorder's files, kills it with SIGKILL and checks what the files hold: every odometry row,
both loops (loops.csv and loop_poses.csv) and the path's trajectory rows, no half-written file.
A recorder that wrote only when stopped left no file at all.
"""
import os
import shutil
import signal
import subprocess
import tempfile
import time
import unittest

import rospy
import rostest
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path
from pipeline_fixture import NS, synthetic_keyframe
from uw_multislam.msg import Keyframe, Loop

RECORDER = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "src", "tools", "record_run.py")
KEYFRAMES = 6


def rows(path):
    try:
        with open(path) as f:
            return f.read().splitlines()[1:]
    except FileNotFoundError:
        return []


def await_rows(files, counts, timeout=30.0):
    """Until each file has its count of rows (polled every 0.1 s); the rows then."""
    deadline = time.time() + timeout
    while time.time() < deadline:
        got = {name: rows(path) for name, path in files.items()}
        if all(len(got[name]) >= n for name, n in counts.items()):
            return got
        time.sleep(0.1)
    raise AssertionError("timed out after %.0f s waiting for %s rows: %s" % (
        timeout, counts, {name: len(rows(path)) for name, path in files.items()}))


class RecordRunKillTest(unittest.TestCase):
    def setUp(self):
        self.tmp = tempfile.mkdtemp(prefix="uwms_record_run_kill_")
        self.out = os.path.join(self.tmp, "run")
        ready = os.path.join(self.tmp, "ready")
        self.log = os.path.join(self.tmp, "record_run.log")
        with open(self.log, "w") as log:
            self.recorder = subprocess.Popen(["/usr/bin/python3", RECORDER, "--out", self.out, "--ns", NS,
                                              "--ready-file", ready], stdout=log, stderr=subprocess.STDOUT)
        deadline = time.time() + 60
        while not os.path.exists(ready):
            if self.recorder.poll() is not None:
                with open(self.log) as f:
                    self.fail("record_run.py stopped: %s" % f.read())
            self.assertLess(time.time(), deadline, "record_run.py not ready within 60 s")
            time.sleep(0.1)

    def tearDown(self):
        if self.recorder.poll() is None:
            self.recorder.kill()
        self.recorder.wait()
        shutil.rmtree(self.tmp, ignore_errors=True)

    def test_a_killed_recorder_keeps_its_rows(self):
        keyframes = rospy.Publisher(NS + "/keyframes", Keyframe, queue_size=100)
        loops = rospy.Publisher(NS + "/loops", Loop, queue_size=100)
        path = rospy.Publisher(NS + "/paths/session_0", Path, queue_size=1, latch=True)
        deadline = time.time() + 30
        while keyframes.get_num_connections() == 0 or loops.get_num_connections() == 0:
            self.assertLess(time.time(), deadline, "record_run.py did not subscribe")
            time.sleep(0.1)
        sent = [synthetic_keyframe(0, k, 0) for k in range(KEYFRAMES)]
        for k in sent:
            keyframes.publish(k)
        for a, b in ((0, 4), (1, 5)):
            loops.publish(Loop(kind=Loop.LOCAL, session_a=0, keyframe_a=a, session_b=0, keyframe_b=b, inliers=50,
                               header=sent[b].header))
        p = Path()
        p.header.frame_id = "map"
        for k in sent:
            pose = PoseStamped(header=k.header)
            pose.pose.position.x, pose.pose.orientation.w = k.odometry_pose.x, 1.0
            p.poses.append(pose)
        path.publish(p)  # latched: the recorder subscribes to it once session 0's first keyframe came
        files = {n: os.path.join(self.out, n + ".csv") for n in ("odometry", "loops", "loop_poses", "trajectory")}
        await_rows(files, {"odometry": KEYFRAMES, "loops": 2, "loop_poses": 2, "trajectory": KEYFRAMES})
        self.assertIsNone(self.recorder.poll(), "the recorder stopped by itself")
        self.recorder.send_signal(signal.SIGKILL)
        self.assertEqual(self.recorder.wait(timeout=30), -signal.SIGKILL)
        got = {name: rows(path) for name, path in files.items()}
        self.assertEqual(got["odometry"], ["0,%d,%.6f,0.000000,0.0000000" % (k, 0.5 * k) for k in range(KEYFRAMES)])
        self.assertEqual(got["loops"], ["0,0,0,4,local,50", "0,1,0,5,local,50"])
        self.assertEqual(len(got["loop_poses"]), 2)
        self.assertEqual([r.split(",")[:4] for r in got["trajectory"]],
                         [["0", str(k), "0", "%.6f" % (0.5 * k)] for k in range(KEYFRAMES)])
        self.assertEqual([n for n in os.listdir(self.out) if n.endswith(".tmp")], [], "a temporary file left")
        print("record_run killed with SIGKILL: %d odometry rows, %d loops, %d trajectory rows kept" % (
            len(got["odometry"]), len(got["loops"]), len(got["trajectory"])))


if __name__ == "__main__":
    rospy.init_node("check_record_run_kill")
    rostest.rosrun("uw_multislam", "check_record_run_kill", RecordRunKillTest)
