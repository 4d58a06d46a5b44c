#!/usr/bin/python3
"""rostest: a REP-103 NED nav gives the same odometry as its ENU twin. Three odometry nodes get the
same frames of the nav prior's mission (session a: 30 blind frames the nav carries) and the same
dead reckoning, each on its own nav/odom:
  enu       as the bag has it: base_link in odom (x east, y north, z up);
  ned       the same poses in odom_ned with child base_link_frd (x north, y east, z down, yaw from
            north towards east), covariance turned with them;
  mirrored  the NED numbers labelled odom / base_link: a NED nav taken for ENU, as before the frames
            were checked.
ned's keyframes and per-frame poses must equal enu's within 1 mm (the map of the session); the
mirrored run must differ by far more (so the comparison can fail).
"""
import math
import os
import shutil
import threading
import unittest

import rospy
import rostest
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import Odometry
from pipeline_fixture import (SENSOR_TOPICS, appender, await_condition, bag_frames, connected, DiagnosticsWatch,
                              make_mission, wait_for_subscribers)
from sensor_msgs.msg import CameraInfo, Image, Range
from uw_multislam.msg import Keyframe

with open(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "nav_blackout_survey.yaml")) as _f:
    MISSION = _f.read()
RUNS = ("enu", "ned", "mirrored")
TOPICS = SENSOR_TOPICS + ["/nav/odom"]


def quaternion_multiply(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz)


def to_ned(enu):
    """The same reading in odom_ned / base_link_frd (REP-103): p_ned = R p_enu, q = R q (x) q_flu_frd,
    R the half turn about (1, 1, 0)/sqrt(2); the covariance turned per block."""
    m = Odometry()
    m.header = enu.header
    m.header.frame_id = "odom_ned"
    m.child_frame_id = "base_link_frd"
    p = enu.pose.pose.position
    m.pose.pose.position.x, m.pose.pose.position.y, m.pose.pose.position.z = p.y, p.x, -p.z
    q = enu.pose.pose.orientation
    r = (math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0)
    o = quaternion_multiply(quaternion_multiply(r, (q.x, q.y, q.z, q.w)), (1.0, 0.0, 0.0, 0.0))
    m.pose.pose.orientation.x, m.pose.pose.orientation.y, m.pose.pose.orientation.z, m.pose.pose.orientation.w = o
    perm, sign = (1, 0, 2), (1, 1, -1)  # R: x' = y, y' = x, z' = -z
    c = enu.pose.covariance
    cov = [0.0] * 36
    for a in range(2):
        for b in range(2):
            for i in range(3):
                for j in range(3):
                    cov[(3 * a + i) * 6 + 3 * b + j] = sign[i] * sign[j] * c[(3 * a + perm[i]) * 6 + 3 * b + perm[j]]
    m.pose.covariance = cov
    return m


def mirrored(enu):
    """The NED numbers, labelled ENU."""
    m = to_ned(enu)
    m.header.frame_id, m.child_frame_id = "odom", "base_link"
    return m


def planar(pose):
    q = pose.orientation
    return pose.position.x, pose.position.y, 2 * math.atan2(q.z, q.w)


class NedNavTest(unittest.TestCase):
    @classmethod
    def status(cls):
        """{run: its odometry's newest values}, for the runs that sent one."""
        return {run: w.get("odometry") for run, w in cls.diagnostics.items() if "odometry" in w.values}

    @classmethod
    def setUpClass(cls):
        cls.tmp, mission = make_mission("uwms_ned_nav_", MISSION)
        cls.frames = bag_frames(os.path.join(mission, "a.bag"), TOPICS)
        cls.lock = threading.Lock()
        cls.poses = {run: [] for run in RUNS}
        cls.keyframes = {run: [] for run in RUNS}
        cls.diagnostics = {run: DiagnosticsWatch(("odometry",), cls.lock, namespace=run) for run in RUNS}
        cls.subs = [rospy.Subscriber("/%s/odometry/pose" % run, PoseWithCovarianceStamped,
                                     appender(cls.lock, cls.poses[run]), queue_size=1000) for run in RUNS]
        cls.subs += [rospy.Subscriber("/%s/keyframes" % run, Keyframe, appender(cls.lock, cls.keyframes[run]),
                                      queue_size=1000) for run in RUNS]
        cls.subs += cls.diagnostics.values()
        cls.pubs = {run: [rospy.Publisher("/%s%s" % (run, t), m, queue_size=100)
                          for t, m in zip(TOPICS, (Image, CameraInfo, Range, Odometry))] for run in RUNS}
        wait_for_subscribers(["/%s%s" % (run, t) for run in RUNS for t in TOPICS], "/check_ned_nav")
        cls.await_condition(lambda: connected([p for run in RUNS for p in cls.pubs[run]]), 30.0, "connections")
        convert = {"enu": lambda m: m, "ned": to_ned, "mirrored": mirrored}
        for i, (image, info, altitude, nav) in enumerate(cls.frames):
            for run in RUNS:
                image_pub, info_pub, altitude_pub, nav_pub = cls.pubs[run]
                nav_pub.publish(convert[run](nav))  # first: the frame finds its reading there
                altitude_pub.publish(altitude)
                info_pub.publish(info)
                image_pub.publish(image)
            # Each frame finished by every node before the next (a node never skips or waits).
            cls.await_condition(lambda: all(cls.status().get(run, {}).get("frames_finished", 0) >= i + 1
                                            for run in RUNS), 30.0, "frame %d finished" % i)
        with cls.lock:
            cls.final = cls.status()

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    @classmethod
    def await_condition(cls, condition, timeout, what):
        await_condition(cls.lock, condition, timeout, what, lambda: "; statuses %s" % cls.status())

    def test_the_ned_nav_is_read_and_used(self):
        for run in RUNS:
            v = self.final[run]
            self.assertEqual(v["nav_received"], len(self.frames), run)
            self.assertEqual(v["nav_refused"], 0, run)
            self.assertEqual(v["frames_processed"], len(self.frames), run)
        self.assertGreater(self.final["ned"]["nav_motions"], 0, "the blind frames carried by the nav")
        self.assertEqual(self.final["ned"]["tracking_losses"], 0)

    def test_ned_gives_the_map_of_enu_within_1_mm(self):
        with self.lock:
            enu, ned = list(self.keyframes["enu"]), list(self.keyframes["ned"])
            enu_poses, ned_poses = list(self.poses["enu"]), list(self.poses["ned"])
        self.assertGreater(len(enu), 5)
        self.assertEqual([(k.session, k.keyframe, k.header.stamp) for k in enu],
                         [(k.session, k.keyframe, k.header.stamp) for k in ned])
        worst = 0.0
        for a, b in zip(enu, ned):
            pa, pb = a.odometry_pose, b.odometry_pose
            worst = max(worst, math.hypot(pa.x - pb.x, pa.y - pb.y))
            self.assertAlmostEqual(math.remainder(pa.theta - pb.theta, 2 * math.pi), 0.0, delta=1e-3)
        self.assertEqual(len(enu_poses), len(ned_poses))
        for a, b in zip(enu_poses, ned_poses):
            self.assertEqual(a.header.stamp, b.header.stamp)
            xa, ya, _ = planar(a.pose.pose)
            xb, yb, _ = planar(b.pose.pose)
            worst = max(worst, math.hypot(xa - xb, ya - yb))
        rospy.loginfo("ned against enu: %d keyframes, %d poses, worst %.6f m", len(enu), len(enu_poses), worst)
        self.assertLess(worst, 0.001)

    def test_a_mirrored_nav_gives_another_map(self):
        with self.lock:
            enu, bad = list(self.poses["enu"]), list(self.poses["mirrored"])
        by_stamp = {p.header.stamp: planar(p.pose.pose) for p in bad}
        worst = max(math.hypot(planar(p.pose.pose)[0] - by_stamp[p.header.stamp][0],
                               planar(p.pose.pose)[1] - by_stamp[p.header.stamp][1])
                    for p in enu if p.header.stamp in by_stamp)
        rospy.loginfo("mirrored against enu: worst %.3f m", worst)
        self.assertGreater(worst, 0.05)


if __name__ == "__main__":
    rospy.init_node("check_ned_nav")
    rostest.rosrun("uw_multislam", "check_ned_nav", NedNavTest)
