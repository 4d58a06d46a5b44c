#!/usr/bin/python3
"""rostest: relocalisation in a stored map, in localisation mode.

The fixture mission's session s0 is mapped by offline_slam into a store. slam.launch then starts on
that store with reload_stored:=true and mode:=localisation, and session s1 (which starts inside s0's
area) is played frame by frame. The back-end must publish relocalised_pose within 3 keyframes of
s1's first keyframe that overlaps s0 (the generator's loops_gt.csv: frame pairs whose centres are
close), with an error of at most 2 cm against the ground truth (world_gt.csv) in s0's map frame;
/diagnostics says "relocalised: session 1 in map 0"; nothing is written to the store (md5).
Registered twice: with slam/loops/page_stored true (the default: the loop detector keeps the stored
keyframes as hashes and reads a candidate's features from the back-end's store, service
keyframe_features) and false (all features sent and kept in RAM); the same relocalisation both ways.
"""
import csv
import hashlib
import math
import os
import shutil
import signal
import subprocess
import threading
import unittest

import rospkg
import rospy
import rostest
from geometry_msgs.msg import PoseWithCovarianceStamped
from sensor_msgs.msg import CameraInfo, Image, Range
from pipeline_fixture import (NS, SENSOR_TOPICS, appender, await_condition, bag_frames, compose, connected,
                              DiagnosticsWatch, invert, make_mission, mount_of_params, stop_launch, tool,
                              vehicle_from_camera)
from uw_multislam.msg import Keyframe
from uw_multislam.srv import ListSessions

WITHIN_KEYFRAMES = 3
SESSIONS_TOOL = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "src", "tools", "sessions.py")
MAX_ERROR_M = 0.02


def md5(path):
    with open(path, "rb") as f:
        return hashlib.md5(f.read()).hexdigest()


def yaw_of(q):
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


class RelocaliseTest(unittest.TestCase):
    def setUp(self):
        self.tmp, self.mission = make_mission("uwms_relocalise_")
        self.db = os.path.join(self.tmp, "store.db")
        subprocess.run([tool("offline_slam"), "--session", os.path.join(self.mission, "s0"), "--db", self.db,
                        "--out", os.path.join(self.tmp, "out0"), "--quiet"], check=True, timeout=300)
        self.md5_before = md5(self.db)
        self.page = rospy.get_param("~page_stored", True)
        # The algorithm parameters with slam/loops/page_stored as this case asks.
        config = os.path.join(self.tmp, "slam.yaml")
        with open(os.path.join(rospkg.RosPack().get_path("uw_multislam"), "config", "slam.yaml")) as f:
            text = f.read()
        self.assertIn("  page_stored: true ", text)
        with open(config, "w") as f:
            f.write(text.replace("  page_stored: true ", "  page_stored: %s " % ("true" if self.page else "false")))
        self.launch = subprocess.Popen(["roslaunch", "uw_multislam", "slam.launch", "camera_mount:=0 0 0 0", "store_path:=" + self.db,
                                        "mode:=localisation", "reload_stored:=true", "slam_config:=" + config],
                                       stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)

    def tearDown(self):
        stop_launch(self.launch)
        shutil.rmtree(self.tmp, ignore_errors=True)

    def test_relocalises_within_three_keyframes_to_two_centimetres(self):
        lock = threading.RLock()
        keyframes, relocalised, poses = [], [], []

        subs = [rospy.Subscriber(NS + "/keyframes", Keyframe, appender(lock, keyframes), queue_size=1000),
                rospy.Subscriber(NS + "/relocalised_pose", PoseWithCovarianceStamped, appender(lock, relocalised),
                                 queue_size=1000),
                rospy.Subscriber(NS + "/odometry/pose", PoseWithCovarianceStamped, appender(lock, poses),
                                 queue_size=1000),
                DiagnosticsWatch(("loop_detector", "backend", "odometry"), lock)]
        status = subs[-1].values  # status name -> its newest values
        with open(os.path.join(self.tmp, "out0", "trajectory.csv")) as f:
            stored = sum(1 for r in csv.DictReader(f) if r["session"] == "0")
        self.assertGreater(stored, 10)
        # The stored keyframes reach the loop detector before the first frame (its diagnostics count them).
        await_condition(lock, lambda: status.get("loop_detector", {}).get("keyframes_reloaded") == stored, 120,
                        "the %d stored keyframes in the loop detector" % stored, lambda: ": %s" % status)
        pubs = [rospy.Publisher(t, m, queue_size=100) for t, m in zip(SENSOR_TOPICS, (Image, CameraInfo, Range))]
        await_condition(lock, lambda: connected(pubs), 60, "the odometry's subscriptions")
        frames = bag_frames(os.path.join(self.mission, "s1.bag"))
        for image, info, altitude in frames:
            pubs[2].publish(altitude)
            pubs[1].publish(info)
            pubs[0].publish(image)
            stamp = image.header.stamp
            await_condition(lock, lambda: any(p.header.stamp == stamp for p in poses), 30, "the odometry pose")
        await_condition(lock, lambda: status.get("backend", {}).get("keyframes_received") == len(keyframes) and
                        status.get("loop_detector", {}).get("keyframes_received") == len(keyframes) and
                        status.get("backend", {}).get("loops_received") == status["loop_detector"].get(
                            "local_loops", 0) + status["loop_detector"].get("global_loops", 0) and
                        status.get("backend", {}).get("queue_length") == 0, 60,
                        "every keyframe and loop in the back-end", lambda: ": %s" % status)
        for s in subs:
            s.unregister()

        with lock:
            self.assertTrue(relocalised, "no relocalised_pose; diagnostics %s" % status)
            first = relocalised[0]
            session = keyframes[0].session
            self.assertTrue(all(k.session == session for k in keyframes), "s1 stayed one session")
            by_stamp = {k.header.stamp: k for k in keyframes}
            self.assertIn(first.header.stamp, by_stamp, "relocalised_pose is stamped with a keyframe's stamp")
            kf = by_stamp[first.header.stamp]
            self.assertEqual(status["backend"]["relocalised"], "session %d in map 0" % session)
            self.assertEqual(status["backend"]["relocalised_map"], 0.0)
            self.assertEqual(status["backend"]["relocalised_poses_published"], len(relocalised))

        # The first keyframe of s1 whose frame overlaps a frame of s0 (the generator's pairs).
        with open(os.path.join(self.mission, "loops_gt.csv")) as f:
            overlapping = {int(r["index_b"]) for r in csv.DictReader(f) if r["session_a"] == "0" and r["session_b"] == "1"}
        first_overlap = min(i for i, k in enumerate(keyframes) if k.frame_index in overlapping)
        which = keyframes.index(kf)
        rospy.loginfo("relocalised at keyframe %d (frame %d); first overlapping keyframe %d (frame %d)", which,
                      kf.frame_index, first_overlap, keyframes[first_overlap].frame_index)
        self.assertLess(which - first_overlap, WITHIN_KEYFRAMES,
                        "relocalised at keyframe %d, the first overlapping one is %d" % (which, first_overlap))

        with open(os.path.join(self.mission, "world_gt.csv")) as f:
            world = {(int(r["session"]), int(r["index"])): (float(r["x_m"]), float(r["y_m"]), float(r["yaw_rad"]))
                     for r in csv.DictReader(f)}
        truth = vehicle_from_camera(compose(invert(world[(0, 0)]), world[(1, kf.frame_index)]), mount_of_params())
        p = first.pose.pose
        error = math.hypot(p.position.x - truth[0], p.position.y - truth[1])
        yaw_error = abs(math.remainder(yaw_of(p.orientation) - truth[2], 2 * math.pi))
        rospy.loginfo("first relocalised pose (%.4f, %.4f, %.4f), truth (%.4f, %.4f, %.4f): error %.4f m, %.4f rad",
                      p.position.x, p.position.y, yaw_of(p.orientation), truth[0], truth[1], truth[2], error,
                      yaw_error)
        self.assertLessEqual(error, MAX_ERROR_M)
        self.assertLess(yaw_error, 0.02)
        cov = first.pose.covariance
        self.assertTrue(cov[0] > 0 and cov[7] > 0 and cov[35] > 0, "a covariance: %s" % list(cov))

        # list_sessions says it too (and sessions.py list prints it); the stored session is not relocalised.
        rospy.wait_for_service(NS + "/list_sessions", timeout=30)
        listed = {s.session: s for s in rospy.ServiceProxy(NS + "/list_sessions", ListSessions)().sessions}
        self.assertEqual(listed[session].relocalised_map, 0)
        self.assertEqual(listed[session].map, session, "relocalised, not joined (localisation mode)")
        self.assertEqual(listed[0].relocalised_map, -1)
        out = subprocess.run([SESSIONS_TOOL, "list"], capture_output=True, text=True, timeout=60)
        self.assertIn("relocalised in map 0", out.stdout, out.stdout + out.stderr)

        # Paging: every stored keyframe held as its hash, the candidates' features read through
        # keyframe_features (misses), none failed; without it, none paged and nothing read.
        with lock:
            detector = status["loop_detector"]
            rospy.loginfo("page_stored %s: loop detector %s", self.page, detector)
            if self.page:
                self.assertEqual(detector["keyframes_paged"], stored, detector)
                self.assertGreater(detector["feature_cache_misses"], 0, detector)
                self.assertGreater(detector["feature_cache_mb"], 0.0, detector)
            else:
                self.assertEqual(detector["keyframes_paged"], 0, detector)
                self.assertEqual(detector["feature_cache_misses"], 0, detector)
            self.assertEqual(detector["feature_read_failures"], 0, detector)

        # A subscriber that comes late (a respawned loop detector) gets every stored keyframe: with
        # its hash only when paging, with its features otherwise.
        late = []
        late_sub = rospy.Subscriber(NS + "/reloaded_keyframes", Keyframe, appender(lock, late), queue_size=1000)
        await_condition(lock, lambda: len(late) >= stored, 60, "the stored keyframes for a late subscriber",
                        lambda: ": %d" % len(late))
        late_sub.unregister()
        with lock:
            self.assertEqual(sorted(k.keyframe for k in late), list(range(stored)))
            self.assertTrue(all(k.session == 0 and len(k.hash) > 0 for k in late))
            self.assertTrue(all((len(k.u_px) == 0) == self.page for k in late), [len(k.u_px) for k in late])

        # Localisation mode: the store is byte-identical, also after the pipeline's clean shutdown.
        self.launch.send_signal(signal.SIGINT)
        self.assertEqual(self.launch.wait(timeout=60), 0)
        self.assertEqual(md5(self.db), self.md5_before)


if __name__ == "__main__":
    rospy.init_node("check_relocalise")
    rostest.rosrun("uw_multislam", "relocalise", RelocaliseTest)
