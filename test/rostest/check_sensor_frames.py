#!/usr/bin/python3
"""rostest: the sensors' frames from their headers, placed on the vehicle by tf. The odometry node
alone, fed frames of a generated mission whose images say frame_id cam_down_optical and whose
altitude readings say dvl (not the default names):

1. No transform for them in tf: every frame is refused and counted (skipped_no_mount), no pose is
   published, and the status is ERROR naming the missing transform base_link -> cam_down_optical.
2. The test publishes a camera tilted 20 degrees from straight down: still refused, the ERROR says
   how far from straight down it is (the 2-D model).
3. The test publishes the right mount (camera 0.3 m forward, 0.1 m down, image columns turned
   0.5 rad; the DVL 0.3 m below the camera): tracking starts at the next frame; the first pose is
   base_link's at the session origin as that mount puts it, each keyframe's altitude is the
   range plus 0.3 m, the keyframes carry the camera's frame_id, and the status is not ERROR.
4. A burst of frames faster than the odometry (~drop_policy newest, the default): frames are
   skipped for newer ones, counted, and every frame is accounted for; no extra session.
5. A second mount publisher moves the camera 0.1 m forward mid-run: the odometry says so once (a
   WARN naming the old and the new mount), counts it (mount_changes) and uses the new mount; no new
   session.
"""
import math
import os
import shutil
import threading
import time
import unittest

import rospy
import rostest
import tf2_ros
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rosgraph_msgs.msg import Log
from geometry_msgs.msg import PoseWithCovarianceStamped, TransformStamped
from pipeline_fixture import (NS, SENSOR_TOPICS, appender, await_condition, bag_frames, connected, diagnostic_values,
                              make_mission, messages_received, wait_for_subscribers)
from sensor_msgs.msg import CameraInfo, Image, Range
from uw_multislam.msg import Keyframe

SURVEY = """
seed: 11
world: {width_m: 12, height_m: 10, metres_per_px: 0.008, featureless_fraction: 0.0}
sessions:
  - name: s0
    camera: {image_width: 240, image_height: 180, fx: 220, fy: 220, cx: 119.5, cy: 89.5}
    mission: {pattern: loop, start_m: [6.0, 5.0], length_m: 1.5, width_m: 1.0, laps: 1.0, speed_m_s: 0.3,
              frame_period_s: 0.1, altitude_m: 1.6, start_time_s: 0}
"""
CAMERA_FRAME, ALTIMETER_FRAME = "cam_down_optical", "dvl"
CAMERA_XYZ, CAMERA_YAW = (0.3, 0.0, -0.1), 0.5
MOVED_XYZ = (0.4, 0.0, -0.1)  # the second mount publisher's camera
ALTIMETER_XYZ = (0.1, 0.05, -0.4)  # 0.3 m below the camera
N_REFUSED, N_TILTED, N_TRACKED, N_BURST, N_MOVED = 8, 4, 30, 24, 20
RATE_HZ = 10.0
ODOMETRY_NODE = NS + "/odometry_node"


def quaternion_multiply(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz)


def optical(yaw, tilt=0.0):
    """The camera's optical frame in base_link: the level frame (yaw about z, then tilted about y) turned by pi about x."""
    level = quaternion_multiply((0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)),
                                (0.0, math.sin(tilt / 2), 0.0, math.cos(tilt / 2)))
    return quaternion_multiply(level, (1.0, 0.0, 0.0, 0.0))


def static(child, xyz, q):
    t = TransformStamped()
    t.header.stamp = rospy.Time.now()
    t.header.frame_id = "base_link"
    t.child_frame_id = child
    t.transform.translation.x, t.transform.translation.y, t.transform.translation.z = xyz
    r = t.transform.rotation
    r.x, r.y, r.z, r.w = q
    return t


class SensorFramesTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp, out = make_mission("uwms_sensor_frames_", SURVEY, timeout=180)
        cls.frames = bag_frames(os.path.join(out, "s0.bag"))
        n = N_REFUSED + N_TILTED + N_TRACKED + N_BURST + N_MOVED
        assert len(cls.frames) >= n, len(cls.frames)
        for image, info, altitude in cls.frames:
            image.header.frame_id = info.header.frame_id = CAMERA_FRAME
            altitude.header.frame_id = ALTIMETER_FRAME
            altitude.range -= 0.3  # the DVL sits 0.3 m below the camera: its range is shorter

        cls.lock = threading.Lock()
        cls.poses, cls.keyframes, cls.statuses, cls.warnings = [], [], [], []

        def on_diagnostics(msg):
            with cls.lock:
                cls.statuses.extend(s for s in msg.status if s.name.endswith(": odometry"))

        cls.subs = [rospy.Subscriber(NS + "/odometry/pose", PoseWithCovarianceStamped, appender(cls.lock, cls.poses),
                                     queue_size=1000),
                    rospy.Subscriber(NS + "/keyframes", Keyframe, appender(cls.lock, cls.keyframes), queue_size=1000),
                    rospy.Subscriber("/diagnostics", DiagnosticArray, on_diagnostics, queue_size=100),
                    rospy.Subscriber("/rosout", Log, lambda m: m.level == Log.WARN and m.name == ODOMETRY_NODE and
                                     appender(cls.lock, cls.warnings)(m.msg), queue_size=1000)]
        cls.pubs = [rospy.Publisher(t, m, queue_size=100) for t, m in zip(SENSOR_TOPICS, (Image, CameraInfo, Range))]
        cls.tf = tf2_ros.StaticTransformBroadcaster()
        cls.buffer = tf2_ros.Buffer()
        cls.listener = tf2_ros.TransformListener(cls.buffer)
        wait_for_subscribers(SENSOR_TOPICS, "/check_sensor_frames")
        cls.await_condition(lambda: connected(cls.pubs), 30.0, "publisher connections")
        cls.sent = 0

        # 1. No mount in tf.
        cls.publish(N_REFUSED, RATE_HZ)
        cls.await_condition(lambda: cls.last().get("skipped_no_mount") == N_REFUSED, 30.0, "the frames refused")
        cls.refused = cls.after_next_status()
        # 2. A tilted camera.
        cls.send_mount([static(CAMERA_FRAME, CAMERA_XYZ, optical(CAMERA_YAW, math.radians(20))),
                        static(ALTIMETER_FRAME, ALTIMETER_XYZ, (0, 0, 0, 1))])
        cls.publish(N_TILTED, RATE_HZ)
        cls.await_condition(lambda: cls.last().get("skipped_no_mount") == N_REFUSED + N_TILTED, 30.0,
                            "the tilted camera's frames refused")
        cls.tilted = cls.after_next_status()
        with cls.lock:
            cls.poses_before_mount = len(cls.poses)
        # 3. The mount (the static broadcaster replaces both transforms).
        cls.send_mount([static(CAMERA_FRAME, CAMERA_XYZ, optical(CAMERA_YAW)),
                        static(ALTIMETER_FRAME, ALTIMETER_XYZ, (0, 0, 0, 1))])
        cls.await_condition(lambda: cls.mounted(), 30.0, "the mount in tf")
        cls.publish(N_TRACKED, RATE_HZ)
        # Every frame accounted for: finished, or skipped for a newer one when the worker fell behind
        # (a loaded machine; newest's skips are deliberate), none still waiting.
        cls.await_condition(lambda: cls.idle(cls.last()) and cls.accounted(cls.last()) == cls.sent, 60.0,
                            "the tracked frames processed")
        cls.tracked = cls.after_next_status()
        with cls.lock:
            cls.tracked_poses = list(cls.poses)
            cls.tracked_keyframes = list(cls.keyframes)
        # 4. A burst: frames as fast as they can be sent.
        cls.publish(N_BURST, None)
        cls.await_condition(lambda: cls.idle(cls.last()) and cls.last().get("images_received") == cls.sent, 60.0,
                            "the burst processed")
        cls.burst = cls.after_next_status()
        cls.sent_by_burst = cls.sent
        # 5. A second mount publisher moves the camera (tf is read again once a second).
        cls.send_mount([static(CAMERA_FRAME, MOVED_XYZ, optical(CAMERA_YAW)),
                        static(ALTIMETER_FRAME, ALTIMETER_XYZ, (0, 0, 0, 1))])
        cls.publish(N_MOVED, RATE_HZ)
        cls.await_condition(lambda: cls.idle(cls.last()) and cls.last().get("images_received") == cls.sent and
                            cls.last().get("mount_changes", 0) >= 1, 60.0, "the moved mount counted")
        cls.moved = cls.after_next_status()

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    @classmethod
    def publish(cls, n, rate_hz):
        start = time.time()
        for k in range(n):
            if rate_hz:
                delay = start + k / rate_hz - time.time()
                if delay > 0:
                    time.sleep(delay)  # the camera's rate, not a wait for a condition
            image, info, altitude = cls.frames[cls.sent]
            cls.pubs[2].publish(altitude)
            cls.pubs[1].publish(info)
            cls.pubs[0].publish(image)
            cls.sent += 1

    @classmethod
    def send_mount(cls, transforms):
        """Publishes the mount on /tf_static and waits until the odometry node has received it. The
        frames that follow travel on other connections, and the odometry waits for a mount only up to
        mount_wait_s after its first frame; since then it takes what its buffer holds. Sent at once, a
        tilted-phase frame could be refused for want of a transform (not for the tilt), an upright-phase
        one as tilted. The test's own listener having the message says nothing of the odometry's."""
        before = messages_received(ODOMETRY_NODE, "/tf_static")
        cls.tf.sendTransform(transforms)
        cls.await_condition(lambda: messages_received(ODOMETRY_NODE, "/tf_static") > before, 30.0,
                            "the mount at the odometry node")

    @classmethod
    def mounted(cls):
        """The test's own listener has the upright camera (the odometry's gets the same latched message)."""
        try:
            q = cls.buffer.lookup_transform("base_link", CAMERA_FRAME, rospy.Time(0)).transform.rotation
        except tf2_ros.TransformException:
            return False
        return abs(abs(q.x) - math.cos(CAMERA_YAW / 2)) < 1e-9

    @classmethod
    def last(cls):
        return diagnostic_values(cls.statuses[-1]) if cls.statuses else {}

    @staticmethod
    def accounted(v):
        return v.get("frames_finished", 0) + v.get("skipped_for_newest", 0) + v.get("dropped_queue_full", 0)

    @staticmethod
    def idle(v):
        return v.get("images_waiting_pairing") == 0 and v.get("queue_length") == 0 and \
            v.get("frames_finished") == v.get("frames_processed")

    @classmethod
    def after_next_status(cls):
        """The first odometry status published from now on (level, message, values)."""
        with cls.lock:
            seen = len(cls.statuses)
        cls.await_condition(lambda: len(cls.statuses) > seen, 10.0, "a new odometry status")
        with cls.lock:
            s = cls.statuses[seen]
        return s.level, s.message, diagnostic_values(s)

    @classmethod
    def await_condition(cls, condition, timeout, what):
        await_condition(cls.lock, condition, timeout, what, lambda: "; last odometry status %s %s" % (
            cls.statuses[-1].message if cls.statuses else "", cls.last()))

    def test_1_without_the_mount_frames_are_refused_naming_the_transform(self):
        level, message, v = self.refused
        self.assertEqual(level, DiagnosticStatus.ERROR, message)
        self.assertIn("base_link -> %s" % CAMERA_FRAME, message)
        self.assertIn("tracking does not start", message)
        self.assertEqual(v["skipped_no_mount"], N_REFUSED)
        self.assertEqual(v["sessions"], 0)

    def test_2_a_tilted_camera_is_refused(self):
        level, message, v = self.tilted
        self.assertEqual(level, DiagnosticStatus.ERROR, message)
        self.assertIn("from straight down", message)
        self.assertEqual(self.poses_before_mount, 0, "no pose while the mount is refused")
        self.assertEqual(v["sessions"], 0)

    def test_3_the_mount_from_tf_places_the_camera_and_the_altimeter(self):
        level, message, v = self.tracked
        self.assertNotEqual(level, DiagnosticStatus.ERROR, message)
        self.assertEqual(v["sessions"], 1)
        self.assertEqual(v["skipped_no_mount"], N_REFUSED + N_TILTED, "no frame refused once the mount is there")
        # One pose per frame the worker finished in this phase: all of them, but those the newest policy
        # skipped if the worker fell behind (a loaded machine), every frame accounted for.
        _, _, before = self.tilted
        finished = v["frames_finished"] - before["frames_finished"]
        self.assertEqual(finished + v["skipped_for_newest"] - before["skipped_for_newest"] +
                         v["dropped_queue_full"] - before["dropped_queue_full"], N_TRACKED)
        self.assertEqual(len(self.tracked_poses), finished)
        self.assertGreaterEqual(finished, N_TRACKED // 2, "most frames processed at 10 Hz")
        # The session's origin is the camera's first pose: base_link sits at the inverse of the mount.
        first = self.tracked_poses[0].pose.pose
        self.assertEqual(self.tracked_poses[0].header.frame_id, "session_0")
        cx, cy, yaw = CAMERA_XYZ[0], CAMERA_XYZ[1], CAMERA_YAW
        self.assertAlmostEqual(first.position.x, -cx * math.cos(yaw) - cy * math.sin(yaw), places=6)
        self.assertAlmostEqual(first.position.y, cx * math.sin(yaw) - cy * math.cos(yaw), places=6)
        self.assertAlmostEqual(2 * math.atan2(first.orientation.z, first.orientation.w), -yaw, places=6)
        ranges = {a.header.stamp: a.range for _, _, a in self.frames}
        self.assertGreaterEqual(len(self.tracked_keyframes), 2)
        for kf in self.tracked_keyframes:
            self.assertEqual(kf.header.frame_id, CAMERA_FRAME)
            self.assertAlmostEqual(kf.altitude_m, ranges[kf.header.stamp] + 0.3, places=6)

    def test_4_a_burst_skips_frames_for_newer_ones_and_counts_every_one(self):
        _, _, v = self.burst
        self.assertGreater(v["skipped_for_newest"], 0, v)
        self.assertEqual(v["frames_synchronised"],
                         v["frames_processed"] + v["dropped_queue_full"] + v["skipped_for_newest"] + v["queue_length"])
        self.assertEqual(v["images_received"], self.sent_by_burst)
        self.assertEqual(v["sessions"], 1, "no extra session")
        self.assertEqual(v["tracking_losses"], 0)
        self.assertEqual(v["time_jumps_forward"], 0, "the skipped stamps are no gap")

    def test_5_a_mount_that_moves_mid_run_is_warned_of_counted_and_used(self):
        _, _, before = self.burst
        _, _, v = self.moved
        self.assertEqual(before["mount_changes"], 0)
        self.assertEqual(v["mount_changes"], 1)
        self.assertEqual(v["sessions"], 1, "no new session")
        with self.lock:
            moved = [w for w in self.warnings if "mount moved in tf" in w]
        self.assertEqual(len(moved), 1, self.warnings)
        self.assertIn("camera at x 0.300 m", moved[0])
        self.assertIn("camera at x 0.400 m", moved[0])


if __name__ == "__main__":
    rospy.init_node("check_sensor_frames")
    rostest.rosrun("uw_multislam", "check_sensor_frames", SensorFramesTest)
