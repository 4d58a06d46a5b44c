#!/usr/bin/python3
"""rostest: the altitude from a DVL's own message, through onboard.launch's relay
(scripts/dvl_altitude.py; dvl:=/dvl/data dvl_altitude:=m.pose.pose.position.z dvl_frame:=dvl_link). nav_msgs/Odometry
stands in for a DVL driver's message (a header and an altitude field). The frames of a generated
mission are published with the altitude only on /dvl/data, the DVL 0.2 m below the camera
(altimeter_mount): every frame is processed, each keyframe's altitude is the DVL's reading plus
0.2 m at its stamp, and a reading of 0 (no bottom lock) is refused like a bad range.
"""
import os
import shutil
import threading
import unittest

import rospy
import rostest
from nav_msgs.msg import Odometry
from pipeline_fixture import (NS, SENSOR_TOPICS, appender, await_condition, bag_frames, connected, DiagnosticsWatch,
                              make_mission, publisher_connected, wait_for_subscribers)
from sensor_msgs.msg import CameraInfo, Image
from uw_multislam.msg import Keyframe

SURVEY = """
seed: 13
world: {width_m: 12, height_m: 10, featureless_fraction: 0.0}
sessions:
  - name: s0
    camera: {image_width: 240, image_height: 180, fx: 220, fy: 220, cx: 119.5, cy: 89.5}
    mission: {pattern: loop, start_m: [6.0, 5.0], length_m: 1.5, width_m: 1.0, laps: 1.0, speed_m_s: 0.3,
              frame_period_s: 0.2, altitude_m: 1.6, start_time_s: 0}
"""
N = 25
DVL_BELOW_CAMERA_M = 0.2


class DvlAltitudeTest(unittest.TestCase):
    @classmethod
    def odometry(cls):
        """The odometry's newest status values."""
        return cls.diagnostics.get("odometry")

    @classmethod
    def setUpClass(cls):
        cls.tmp, out = make_mission("uwms_dvl_", SURVEY, timeout=180)
        cls.frames = bag_frames(os.path.join(out, "s0.bag"))[:N]
        assert len(cls.frames) == N
        cls.lock = threading.Lock()
        cls.keyframes = []
        cls.diagnostics = DiagnosticsWatch(("odometry",), cls.lock)
        cls.subs = [rospy.Subscriber(NS + "/keyframes", Keyframe, appender(cls.lock, cls.keyframes), queue_size=1000),
                    cls.diagnostics]
        topics = SENSOR_TOPICS[:2] + ["/dvl/data"]
        cls.pubs = [rospy.Publisher(t, m, queue_size=100) for t, m in zip(topics, (Image, CameraInfo, Odometry))]
        wait_for_subscribers(SENSOR_TOPICS[:2] + ["/dvl/data"], "/check_dvl_altitude")
        cls.await_condition(lambda: connected(cls.pubs), 30.0, "publisher connections")
        # The relay's own publisher too: it is made when the relay starts, and the odometry connects to
        # it on the master's word; a reading relayed before that would be lost (not queued, not latched).
        cls.await_condition(lambda: publisher_connected(NS + "/dvl_altitude", NS + "/dvl_altitude"), 30.0,
                            "the relay's connection to the odometry")
        cls.readings = {}
        for i, (image, info, altitude) in enumerate(cls.frames):
            dvl = Odometry()
            dvl.header.stamp = altitude.header.stamp
            dvl.header.frame_id = "odom"  # a driver's frame that is not the DVL's: dvl_frame overrides it
            # The last reading has no bottom lock (0): refused, its frame takes the reading before.
            dvl.pose.pose.position.z = altitude.range - DVL_BELOW_CAMERA_M if i < N - 1 else 0.0
            cls.readings[altitude.header.stamp] = dvl.pose.pose.position.z
            cls.pubs[2].publish(dvl)
            cls.pubs[1].publish(info)
            cls.pubs[0].publish(image)
            cls.await_condition(lambda: cls.odometry().get("frames_finished", 0) >= i + 1, 30.0, "frame %d" % i)
        with cls.lock:
            cls.final = dict(cls.odometry())
            cls.kfs = list(cls.keyframes)

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    @classmethod
    def await_condition(cls, condition, timeout, what):
        await_condition(cls.lock, condition, timeout, what, lambda: "; odometry status %s" % cls.odometry())

    def test_every_frame_takes_the_dvls_altitude(self):
        v = self.final
        self.assertEqual(v["altitudes_received"], N)
        self.assertEqual(v["altitudes_refused"], 1, "the reading of 0 (no bottom lock)")
        self.assertEqual(v["frames_processed"], N)
        self.assertEqual(v["skipped_no_altitude"], 0)
        self.assertEqual(v["skipped_no_mount"], 0, "base_link -> dvl_link from altimeter_mount")
        self.assertEqual(v["sessions"], 1)

    def test_keyframe_altitudes_are_the_dvls_plus_its_mount(self):
        self.assertGreaterEqual(len(self.kfs), 2)
        for kf in self.kfs:
            reading = self.readings[kf.header.stamp]
            if reading > 0:
                self.assertAlmostEqual(kf.altitude_m, reading + DVL_BELOW_CAMERA_M, places=5)


if __name__ == "__main__":
    rospy.init_node("check_dvl_altitude")
    rostest.rosrun("uw_multislam", "check_dvl_altitude", DvlAltitudeTest)
