#!/usr/bin/python3
"""rostest: altitude by stamp. A 10 Hz camera with a 2 Hz altimeter: every image
is processed, each with the altitude interpolated at its stamp.

The frames of a generated mission (make_survey, 0.1 s apart, read back from its bag) are
published at 10 Hz (image + camera_info, their own stamps); the altitude only with every 5th
frame (2 Hz). The last images come after the last altitude reading: they wait
~altitude_max_age_s, then take the last reading (it is within the bound). The assertions read the
odometry's last status on /diagnostics (awaited until every image has been processed) and the
keyframes' altitudes (linear between the two readings around each keyframe's stamp).
"""
import os
import shutil
import threading
import time
import unittest

import rospy
import rostest
from geometry_msgs.msg import PoseWithCovarianceStamped
from pipeline_fixture import (NS, SENSOR_TOPICS, appender, await_condition, bag_frames, connected, DiagnosticsWatch,
                              make_mission, wait_for_subscribers)
from sensor_msgs.msg import CameraInfo, Image, Range
from uw_multislam.msg import Keyframe

SURVEY = """
seed: 7
world: {width_m: 12, height_m: 10, metres_per_px: 0.008, featureless_fraction: 0.0}
sessions:
  - name: s0
    camera: {image_width: 240, image_height: 180, fx: 220, fy: 220, cx: 119.5, cy: 89.5}
    mission: {pattern: loop, start_m: [6.0, 5.0], length_m: 1.5, width_m: 1.0, laps: 1.0, speed_m_s: 0.35,
              frame_period_s: 0.1, altitude_m: 1.6, start_time_s: 0}
"""
N_IMAGES = 60
CAMERA_HZ = 10.0
ALTITUDE_EVERY = 5  # 2 Hz
LAST_WITH_ALTITUDE = 54  # images 55..59 come after the last reading



# altitude_by_stamp.test's mount: camera at z -0.10 m, altimeter at z -0.35 m in base_link.
CAMERA_ABOVE_ALTIMETER_M = 0.25

class AltitudeByStampTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp, out = make_mission("uwms_altitude_", SURVEY, timeout=180)
        cls.frames = bag_frames(os.path.join(out, "s0.bag"))[:N_IMAGES]
        assert len(cls.frames) == N_IMAGES, len(cls.frames)

        cls.lock = threading.Lock()
        cls.poses, cls.keyframes = [], []
        cls.diagnostics = DiagnosticsWatch(("odometry",), cls.lock)
        cls.subs = [rospy.Subscriber(NS + "/odometry/pose", PoseWithCovarianceStamped, appender(cls.lock, cls.poses),
                                     queue_size=1000),
                    rospy.Subscriber(NS + "/keyframes", Keyframe, appender(cls.lock, cls.keyframes), queue_size=1000),
                    cls.diagnostics]
        cls.pubs = [rospy.Publisher(t, m, queue_size=100) for t, m in zip(SENSOR_TOPICS, (Image, CameraInfo, Range))]
        wait_for_subscribers(SENSOR_TOPICS, "/check_altitude_by_stamp")
        cls.await_condition(lambda: connected(cls.pubs), 30.0, "publisher connections")

        # Publish: images + camera_info at 10 Hz, the altitude with every 5th image.
        cls.readings = []  # (stamp s, altitude m) as sent
        start = time.time()
        for i, (image, info, altitude) in enumerate(cls.frames):
            delay = start + i / CAMERA_HZ - time.time()
            if delay > 0:
                time.sleep(delay)  # the camera's rate, not a wait for a condition
            cls.pubs[0].publish(image)
            cls.pubs[1].publish(info)
            if i % ALTITUDE_EVERY == 0:
                altitude.range -= CAMERA_ABOVE_ALTIMETER_M  # the altimeter sits lower: its range is shorter
                cls.pubs[2].publish(altitude)
                cls.readings.append((altitude.header.stamp.to_sec(), altitude.range))
        cls.publish_s = time.time() - start

        def done():
            v = cls.diagnostics.get("odometry")
            return (v.get("images_received") == N_IMAGES and v.get("images_waiting_pairing") == 0 and
                    v.get("queue_length") == 0 and v.get("frames_processed") == v.get("frames_synchronised") and
                    len(cls.poses) >= v.get("frames_processed", float("inf")))
        cls.await_condition(done, 60.0, "every image received, paired or skipped, and processed")
        with cls.lock:
            cls.final = cls.diagnostics.get("odometry")
            cls.n_poses = len(cls.poses)
            cls.kfs = list(cls.keyframes)
        rospy.loginfo("altitude by stamp: %d images sent at %.0f Hz in %.1f s, %d altitudes at %.0f Hz; odometry: "
                      "%d received, %d synchronised, %d processed, %d poses, %d skipped for altitude, %d keyframes",
                      N_IMAGES, CAMERA_HZ, cls.publish_s, len(cls.readings), CAMERA_HZ / ALTITUDE_EVERY,
                      cls.final["images_received"], cls.final["frames_synchronised"], cls.final["frames_processed"],
                      cls.n_poses, cls.final["skipped_no_altitude"], len(cls.kfs))

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    @classmethod
    def await_condition(cls, condition, timeout, what):
        await_condition(cls.lock, condition, timeout, what, lambda: "; last odometry status %s" % (
            cls.diagnostics.get("odometry") or None))

    def interpolated(self, stamp):
        r = self.readings
        if stamp >= r[-1][0]:
            return r[-1][1]
        for (ta, aa), (tb, ab) in zip(r, r[1:]):
            if ta <= stamp <= tb:
                return aa + (stamp - ta) / (tb - ta) * (ab - aa)
        raise AssertionError("stamp %.3f before the first reading" % stamp)

    def test_every_image_is_processed(self):
        v = self.final
        self.assertEqual(len(self.readings), N_IMAGES // ALTITUDE_EVERY)
        self.assertEqual(v["altitudes_received"], len(self.readings))
        self.assertEqual(v["images_received"], N_IMAGES)
        self.assertEqual(v["frames_synchronised"], N_IMAGES, "images were left unpaired")
        self.assertEqual(v["frames_processed"], N_IMAGES)
        self.assertEqual(v["images_not_paired"], 0)
        for key in ("skipped_no_altitude", "skipped_no_camera_info", "bad_altitude_replaced", "fixed_altitude_frames",
                    "dropped_queue_full", "skipped_by_odometry", "skipped_duplicate_stamp", "skipped_out_of_order"):
            self.assertEqual(v[key], 0, key)
        self.assertEqual(self.n_poses, N_IMAGES, "one pose per image")

    def test_keyframe_altitudes_are_interpolated_at_their_stamps(self):
        self.assertGreaterEqual(len(self.kfs), 2)
        between = 0
        for kf in self.kfs:
            stamp = kf.header.stamp.to_sec()
            # The camera's altitude: the altimeter's range plus the camera's height above it (the mount).
            self.assertAlmostEqual(kf.altitude_m, self.interpolated(stamp) + CAMERA_ABOVE_ALTIMETER_M, places=6,
                                   msg="keyframe at %.3f" % stamp)
            between += all(abs(stamp - t) > 1e-6 for t, _ in self.readings)
        self.assertGreater(between, 0, "no keyframe between two readings: the interpolation was not exercised")


if __name__ == "__main__":
    rospy.init_node("check_altitude_by_stamp")
    rostest.rosrun("uw_multislam", "check_altitude_by_stamp", AltitudeByStampTest)
