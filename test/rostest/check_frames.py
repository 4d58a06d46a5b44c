#!/usr/bin/python3
"""rostest: the back-end beside a vehicle's own navigation (REP-105 frames).

The vehicle's nav stack is this test: for every image it broadcasts odom -> base_link at the
image's stamp, from the ground truth (odom = the survey's world frame), and the back-end runs
with ~publish_odom_tf false, so it publishes only map -> odom. The bags play with --clock
(use_sim_time).

1. While the bags play, base_link is looked up in map at random times between the last images:
   every lookup succeeds, and in session 0 (whose first frame is the map) the pose is the ground
   truth within TOLERANCE_M.
2. map -> odom goes out with strictly increasing stamps (no TF_REPEATED_DATA), and /diagnostics
   reports its rate, about ~tf_rate (20 Hz).
3. keyframe_pose (PoseWithCovarianceStamped) carries what the core computes: its mean and
   covariance are recomputed here, independently, by composing session 1's optimised motions
   (session_trajectory) with the odometry's motion covariances (Keyframe messages) to first order.
4. After join_sessions(0, 1), with the clock running (the test keeps it and the vehicle's odom
   going after the bags end), base_link looked up in map at the latest time moves to session 1's
   place in session 0's map within 0.1 s of the service's answer.
"""
import csv
import math
import os
import random
import shutil
import subprocess
import threading
import time
import unittest

import rospy
import rostest
import tf2_ros
from geometry_msgs.msg import PoseWithCovarianceStamped, TransformStamped
from pipeline_fixture import (NS, SENSOR_TOPICS, DiagnosticsWatch, appender, chain_covariance, compose,
                              frames_by_stamp, invert, make_mission, map_origin, matmul3, mount_of_params, transpose3,
                              vehicle_from_camera, wait_for_subscribers, wait_until_quiet)
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Image
from tf2_msgs.msg import TFMessage
from uw_multislam.msg import Keyframe, SessionTrajectory
from uw_multislam.srv import JoinSessions, ListSessions

TOLERANCE_M = 0.10  # SLAM's pose of base_link in session 0 vs the ground truth (the odometry drifts ~cm)
JOIN_LATENCY_S = 0.1
MOUNT = (0.0, 0.0, 0.0)  # the camera in base_link (x, y, yaw): frames.test's camera_mount, read from tf at start


def transform(parent, child, stamp, x, y, yaw):
    t = TransformStamped()
    t.header.stamp = stamp
    t.header.frame_id = parent
    t.child_frame_id = child
    t.transform.translation.x, t.transform.translation.y = x, y
    t.transform.rotation.z, t.transform.rotation.w = math.sin(yaw / 2), math.cos(yaw / 2)
    return t


def planar(t):
    q = t.transform.rotation
    return t.transform.translation.x, t.transform.translation.y, 2.0 * math.atan2(q.z, q.w)


def in_frame(origin, p):
    """p (world, the camera's) in the frame whose origin is `origin` (world), as the vehicle's pose
    there: base_link in the z-up frame of session 0's first image, as the map frame has it."""
    return vehicle_from_camera(compose(invert(origin), p), MOUNT)


class FramesTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp, cls.mission = make_mission("uwms_frames_")
        with open(os.path.join(cls.mission, "world_gt.csv")) as f:
            cls.world = {(int(r["session"]), int(r["index"])): (float(r["x_m"]), float(r["y_m"]), float(r["yaw_rad"]))
                         for r in csv.DictReader(f)}
        cls.frames = frames_by_stamp(cls.mission)  # image stamp -> (session, index) of world_gt.csv
        cls.lock = threading.Lock()
        cls.images = []  # (stamp, session, index)
        cls.map_odom_stamps = []
        cls.lookups = {"ok": 0, "failed": [], "session0": []}  # session0: (pose in map, image a, image b, u)
        cls.buffer = tf2_ros.Buffer(rospy.Duration(3600))
        cls.listener = tf2_ros.TransformListener(cls.buffer)
        cls.broadcaster = tf2_ros.TransformBroadcaster()

        def on_image(msg):
            stamp = msg.header.stamp
            session, index = cls.frames[stamp.to_nsec()]
            with cls.lock:
                cls.images.append((stamp, session, index))
            # The vehicle's navigation: base_link (not the camera) in a z-up odom.
            x, y, yaw = vehicle_from_camera(cls.world[(session, index)], MOUNT)
            cls.broadcaster.sendTransform(transform("odom", "base_link", stamp, x, y, yaw))
            cls.check_between_images()

        def on_tf(msg):
            with cls.lock:
                for t in msg.transforms:
                    if t.header.frame_id == "map" and t.child_frame_id == "odom":
                        cls.map_odom_stamps.append(t.header.stamp)

        cls.keyframes, cls.trajectories, cls.keyframe_poses = [], [], []
        cls.last_trajectory = [time.time()]  # when the back-end last published a session trajectory

        def on_trajectory(msg):
            with cls.lock:
                cls.trajectories.append(msg)
                cls.last_trajectory[0] = time.time()

        cls.diagnostics = DiagnosticsWatch(("backend",), cls.lock, history=True)  # map_to_odom_rate_hz over time
        cls.subs = [rospy.Subscriber(NS + "/keyframes", Keyframe, appender(cls.lock, cls.keyframes), queue_size=1000),
                    rospy.Subscriber(NS + "/session_trajectory", SessionTrajectory, on_trajectory, queue_size=1000),
                    rospy.Subscriber(NS + "/keyframe_pose", PoseWithCovarianceStamped, appender(cls.lock, cls.keyframe_poses),
                                     queue_size=1000),
                    rospy.Subscriber("/camera/image_raw", Image, on_image, queue_size=100),
                    rospy.Subscriber("/tf", TFMessage, on_tf, queue_size=1000),
                    cls.diagnostics]
        rospy.wait_for_service(NS + "/join_sessions", timeout=60)
        cls.join = rospy.ServiceProxy(NS + "/join_sessions", JoinSessions)
        cls.list = rospy.ServiceProxy(NS + "/list_sessions", ListSessions)
        wait_for_subscribers(["/camera/image_raw", NS + "/keyframes", NS + "/loops"], "/check_frames")
        for name in ("s0", "s1"):
            subprocess.run(["rosbag", "play", "-q", "--wait-for-subscribers", "--clock", "-d", "1", "-r", "4",
                            os.path.join(cls.mission, name + ".bag"), "--topics"] + SENSOR_TOPICS, check=True,
                           timeout=120)
        with cls.lock:
            cls.rates_while_playing = [v["map_to_odom_rate_hz"] for v in cls.diagnostics.history.get("backend", [])]
        # The bags are over: the vehicle's clock and odometry go on (it holds its last pose).
        cls.stop = threading.Event()
        cls.clock_thread = threading.Thread(target=cls.keep_time)
        cls.clock_thread.start()
        # The back-end's queue drains at bag speed and the last loops arrive: until it has published
        # no trajectory for 3 s.
        wait_until_quiet(cls.lock, lambda: cls.last_trajectory[0], 3.0, timeout=60.0)

    @classmethod
    def keep_time(cls):
        pub = rospy.Publisher("/clock", Clock, queue_size=10)
        with cls.lock:
            now, session, index = cls.images[-1]
        pose = vehicle_from_camera(cls.world[(session, index)], MOUNT)
        start = time.monotonic()
        while not cls.stop.is_set():
            t = now + rospy.Duration(time.monotonic() - start)
            pub.publish(Clock(clock=t))
            cls.broadcaster.sendTransform(transform("odom", "base_link", t, *pose))
            time.sleep(0.01)

    @classmethod
    def tearDownClass(cls):
        cls.stop.set()
        cls.clock_thread.join()
        shutil.rmtree(cls.tmp, ignore_errors=True)

    @classmethod
    def check_between_images(cls):
        """base_link in map at a random time between the two images before the last one."""
        with cls.lock:
            if len(cls.images) < 3 or not cls.map_odom_stamps or cls.images[-3][1] != cls.images[-1][1]:
                return
            (a, session, ia), (b, _, ib) = cls.images[-3], cls.images[-2]
            if cls.map_odom_stamps[0] > a:
                return  # map -> odom did not exist yet
        u = random.random()
        t = a + rospy.Duration(u * (b - a).to_sec())
        try:
            got = planar(cls.buffer.lookup_transform("map", "base_link", t, rospy.Duration(2.0)))
        except (tf2_ros.LookupException, tf2_ros.ExtrapolationException, tf2_ros.ConnectivityException) as e:
            with cls.lock:
                cls.lookups["failed"].append("%.3f: %s" % (t.to_sec(), e))
            return
        with cls.lock:
            cls.lookups["ok"] += 1
            if session == 0:  # compared with the truth once map 0's origin is known (test 1)
                cls.lookups["session0"].append((got, ia, ib, u))

    @classmethod
    def origin(cls):
        """The ground truth of map 0's origin (the image of session 0's first keyframe)."""
        with cls.lock:
            return cls.world[map_origin(cls.keyframes, cls.frames)]

    def test_1_base_link_in_map_at_any_time_between_images(self):
        with self.lock:
            ok, failed, session0 = self.lookups["ok"], list(self.lookups["failed"]), list(self.lookups["session0"])
        origin = self.origin()
        errors = []
        for got, ia, ib, u in session0:  # the truth between the two images, interpolated
            pa, pb = self.world[(0, ia)], self.world[(0, ib)]
            truth = (pa[0] + u * (pb[0] - pa[0]), pa[1] + u * (pb[1] - pa[1]),
                     pa[2] + u * math.remainder(pb[2] - pa[2], 2 * math.pi))
            tx, ty, _ = in_frame(origin, truth)
            errors.append(math.hypot(got[0] - tx, got[1] - ty))
        print("base_link in map between images: %d lookups, %d failed, session 0: worst %.3f m, mean %.3f m from the "
              "ground truth" % (ok, len(failed), max(errors or [0]), sum(errors) / max(1, len(errors))))
        self.assertEqual(failed, [])
        self.assertGreaterEqual(ok, 40)
        self.assertGreaterEqual(len(errors), 20)
        self.assertLess(max(errors), TOLERANCE_M, "worst %.3f m, mean %.3f m" % (max(errors), sum(errors) / len(errors)))

    def test_2_fresh_stamps_and_the_rate_in_diagnostics(self):
        with self.lock:
            stamps = list(self.map_odom_stamps)
            rates = list(self.rates_while_playing)
        self.assertGreater(len(stamps), 100)
        repeated = sum(1 for s, t in zip(stamps, stamps[1:]) if t <= s)
        self.assertEqual(repeated, 0)
        self.assertGreater(len(rates), 5)
        busy = [r for r in rates if r > 0]
        median = sorted(busy)[len(busy) // 2]
        print("map -> odom: %d stamps, %d repeated, median rate in /diagnostics %.1f Hz" % (len(stamps), repeated, median))
        self.assertGreater(median, 15.0)  # ~tf_rate = 20 Hz while the clock runs
        self.assertLess(median, 30.0)

    def test_3_keyframe_pose_carries_the_cores_covariance(self):
        # Session 1, the active one at the end of the bags (a map of its own: automatic joining
        # is off): its last session_trajectory and keyframe_pose come from one publication.
        with self.lock:
            keyframes = [k for k in self.keyframes if k.session == 1]
            trajectory = [t for t in self.trajectories if t.session == 1][-1]
            last = self.keyframe_poses[-1]
        self.assertEqual(last.header.stamp, trajectory.header.stamp)
        poses = trajectory.poses
        covariances = {k.keyframe: [list(k.motion_covariance[3 * r:3 * r + 3]) for r in range(3)] for k in keyframes}
        self.assertEqual(sorted(covariances), list(range(len(poses))))
        # First-order composition, written out (pipeline_fixture.chain_covariance); the session's
        # frame is its first keyframe's, so the last pose in it is the composed mean.
        self.assertEqual((poses[0].x, poses[0].y, poses[0].theta), (0.0, 0.0, 0.0))
        cov = chain_covariance([(p.x, p.y, p.theta) for p in poses],
                               [covariances.get(k) for k in range(len(poses))])
        x, y, yaw = poses[-1].x, poses[-1].y, poses[-1].theta
        mat, tr = matmul3, transpose3
        # The vehicle's (doc/frames.md): z-up flips y and yaw (F = diag(1, -1, -1)), then (+) the
        # inverse mount, whose Jacobian in its first argument is J1 again.
        f = [[1, 0, 0], [0, -1, 0], [0, 0, -1]]
        cov = mat(mat(f, cov), f)
        b = invert(MOUNT)
        c, s = math.cos(-yaw), math.sin(-yaw)
        j1 = [[1, 0, -s * b[0] - c * b[1]], [0, 1, c * b[0] - s * b[1]], [0, 0, 1]]
        cov = mat(mat(j1, cov), tr(j1))
        x, y, yaw = vehicle_from_camera((x, y, yaw), MOUNT)
        got = last.pose.pose
        self.assertAlmostEqual(got.position.x, x, delta=1e-9)
        self.assertAlmostEqual(got.position.y, y, delta=1e-9)
        self.assertAlmostEqual(2 * math.atan2(got.orientation.z, got.orientation.w), yaw, delta=1e-9)
        slots = (0, 1, 5)  # x, y, yaw of the 6 x 6 (x, y, z, roll, pitch, yaw)
        worst = max(abs(last.pose.covariance[6 * slots[i] + slots[j]] - cov[i][j]) for i in range(3) for j in range(3))
        scale = max(abs(v) for r in cov for v in r)
        print("keyframe_pose: %d keyframes composed, covariance worst difference %.2e of %.2e" % (len(poses), worst, scale))
        self.assertLess(worst, 1e-9 * scale)
        for unknown in (2, 3, 4):  # z, roll, pitch: unknown, as robot_localization reads it
            self.assertGreaterEqual(last.pose.covariance[7 * unknown], 1e5)

    def test_4_after_a_join_base_link_moves_to_the_joined_map_within_0_1_s(self):
        with self.lock:
            _, session, index = self.images[-1]
        self.assertEqual(session, 1)
        here = self.world[(1, index)]
        in_map0 = in_frame(self.origin(), here)
        before = planar(self.buffer.lookup_transform("map", "base_link", rospy.Time(0), rospy.Duration(2.0)))
        # The mount's static tf (frames.test's camera_mount, for the images' frame) looks straight down.
        optical = self.buffer.lookup_transform("base_link", "camera", rospy.Time(0)).transform
        self.assertAlmostEqual(optical.translation.x, 0.35, delta=1e-9)
        self.assertAlmostEqual(MOUNT[2], 0.4, delta=1e-9)  # the camera's yaw as the test reads it
        self.assertAlmostEqual(abs(optical.rotation.w) + abs(optical.rotation.z), 0.0, delta=1e-9)  # pi about a level axis
        # Before the join session 1 is a map of its own: base_link is far from its place in map 0.
        self.assertGreater(math.hypot(before[0] - in_map0[0], before[1] - in_map0[1]), 0.5)
        res = self.join(0, 1, 0)
        answered = time.monotonic()
        self.assertEqual(res.status.code, 0, res.status.message)
        moved = None
        while time.monotonic() - answered < 2.0:
            got = planar(self.buffer.lookup_transform("map", "base_link", rospy.Time(0)))
            if math.hypot(got[0] - in_map0[0], got[1] - in_map0[1]) < TOLERANCE_M:
                moved = time.monotonic() - answered
                break
            time.sleep(0.002)
        self.assertIsNotNone(moved, "base_link never reached its place in the joined map")
        print("base_link in the joined map %.3f s after join_sessions answered" % moved)
        self.assertLess(moved, JOIN_LATENCY_S)


if __name__ == "__main__":
    rospy.init_node("check_frames")
    MOUNT = mount_of_params()
    rostest.rosrun("uw_multislam", "check_frames", FramesTest)
