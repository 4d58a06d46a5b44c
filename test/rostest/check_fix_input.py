#!/usr/bin/python3
"""rostest fix_input.test: NavSatFix messages as absolute position priors on the back-end's keyframes.
The test sends five keyframes whose odometry drifts 0.25 m to the side per 2 m motion (keyframe 4
at (8, -1) in the z-up map, the truth (8, 0)); then, with stamps of keyframes it sent, a NO_FIX fix,
a fix with a NaN latitude, and a good fix at the truth (sigma 0.1 m east and north) of a GPS antenna
1.0 m forward and 0.5 m to port of base_link (frame gps; the test publishes base_link -> gps as static tf),
twice (the second refused: one fix per keyframe), its latitude/longitude worked out here from the datum with plain WGS84 arithmetic (check_datum.py's),
and a fix 200 m off (a USBL's multipath) on keyframe 3 with the same small covariance (refused by the gate).
Checks: keyframe_pose of keyframe 4 moves toward the fix by the fraction the covariances predict
(odometry's lateral variance over the leg against the fix's, written out here), keyframe_fix with
it, and /diagnostics counts fixes_used 1, fixes_refused_no_fix 1, fixes_refused_not_finite 1,
fixes_refused_keyframe_has_fix 1, fixes_refused_outlier 1."""
import math
import os
import sys
import time
import unittest

import rospy
import rostest
import tf2_ros
from geometry_msgs.msg import TransformStamped
from sensor_msgs.msg import NavSatFix, NavSatStatus

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from check_datum import Recorder, datum_frame, geodetic  # noqa: E402
from pipeline_fixture import backend_values, connected  # noqa: E402
from uw_multislam.msg import Keyframe  # noqa: E402

NS = "/uw_multislam"
LAT, LON, HEADING = 43.0951, 5.9307, 30.0  # fix_input.test's datum
MOTION = (2.0, 0.25, 0.0)  # the odometry's motion in the camera's image axes (z-up: y -> -y)
MOTION_VAR = (0.01, 0.01, 1e-4)
FIX_VAR = 0.01
ANTENNA = (1.0, 0.5)  # base_link -> gps: the lever arm the back-end must take from tf


def await_connected(publisher, what, timeout=45.0):
    deadline = time.time() + timeout
    while time.time() < deadline and not connected([publisher]):
        time.sleep(0.1)
    if not connected([publisher]):
        raise AssertionError("the back-end never connected to this test's " + what)


def map_to_wgs84(x, y):
    origin, x_axis, y_axis, _ = datum_frame(LAT, LON, HEADING)
    lat, lon, _ = geodetic(tuple(origin[i] + x * x_axis[i] + y * y_axis[i] for i in range(3)))
    return lat, lon


def in_keyframe_axes(position):
    """A position published in map (ENU at the datum) in the first keyframe's z-up axes, whose x
    axis has compass heading HEADING: x along (sin H, cos H) in (east, north), y along (-cos H, sin H)."""
    h = math.radians(HEADING)
    e, n = position.x, position.y
    return e * math.sin(h) + n * math.cos(h), -e * math.cos(h) + n * math.sin(h)


def predicted_fraction():
    """How far (0..1) keyframe 4 moves toward a fix straight across the leg: the odometry's
    lateral variance at keyframe 4 (each motion's lateral variance, and each yaw error times the
    distance still to go, squared) against the fix's. The leg's heading drift is atan(0.25/2)."""
    lateral = 4 * MOTION_VAR[1] + MOTION_VAR[2] * sum((2.0 * math.hypot(1, 0.125) * k) ** 2 for k in (3, 2, 1, 0))
    return lateral / (lateral + FIX_VAR)


class FixInputTest(unittest.TestCase):
    def test_fixes_pull_the_keyframe_and_refusals_are_counted(self):
        recorder = Recorder()
        recorder.connect(with_fix=True)
        mount = tf2_ros.StaticTransformBroadcaster()
        arm = TransformStamped()
        arm.header.stamp = rospy.Time.now()
        arm.header.frame_id, arm.child_frame_id = "base_link", "gps"
        arm.transform.translation.x, arm.transform.translation.y = ANTENNA
        arm.transform.rotation.w = 1.0
        mount.sendTransform(arm)
        await_connected(mount.pub_tf, "tf_static")  # latched: the back-end has it once connected
        keyframes = rospy.Publisher(NS + "/keyframes", Keyframe, queue_size=10)
        fixes = rospy.Publisher(NS + "/fix", NavSatFix, queue_size=10)
        await_connected(keyframes, "keyframes")
        await_connected(fixes, "fix")
        t0 = rospy.Time.now()
        for k in range(5):
            msg = Keyframe(session=0, keyframe=k, frame_index=k, altitude_m=2.0, width=240, height=180, fx=220,
                           fy=220, cx=119.5, cy=89.5, descriptor_size=128,
                           status=Keyframe.FIRST if k == 0 else Keyframe.MATCHED)
            msg.header.stamp = t0 + rospy.Duration(k)
            if k > 0:
                msg.motion.x, msg.motion.y, msg.motion.theta = MOTION
                msg.motion_covariance = [MOTION_VAR[0], 0, 0, 0, MOTION_VAR[1], 0, 0, 0, MOTION_VAR[2]]
            msg.odometry_pose.x, msg.odometry_pose.y = MOTION[0] * k, MOTION[1] * k
            keyframes.publish(msg)
        last = t0 + rospy.Duration(4)
        got = recorder.at(last, with_fix=True)
        self.assertIsNotNone(got, "no keyframe_pose/keyframe_fix of keyframe 4")
        before, before_fix = got
        bx, by = in_keyframe_axes(before.pose.pose.position)
        print("keyframe 4 before the fix: (%.3f, %.3f)" % (bx, by))
        self.assertAlmostEqual(bx, 8.0, delta=0.05)
        self.assertAlmostEqual(by, -1.0, delta=0.05)  # the drift, z up

        lat, lon = map_to_wgs84(8.0, 0.0)  # base_link's true position
        # The antenna's: the vehicle heads along the leg's x (the odometry's yaw is 0 throughout).
        gps_lat, gps_lon = map_to_wgs84(8.0 + ANTENNA[0], 0.0 + ANTENNA[1])
        known = NavSatFix.COVARIANCE_TYPE_KNOWN
        bad = [NavSatFix(status=NavSatStatus(status=NavSatStatus.STATUS_NO_FIX), latitude=lat, longitude=lon,
                         position_covariance_type=known),
               NavSatFix(latitude=float("nan"), longitude=lon, position_covariance_type=known)]
        good = NavSatFix(latitude=gps_lat, longitude=gps_lon, position_covariance_type=known,
                         position_covariance=[FIX_VAR, 0, 0, 0, FIX_VAR, 0, 0, 0, 1.0])
        jump_lat, jump_lon = map_to_wgs84(6.0, 200.0)
        jump = NavSatFix(latitude=jump_lat, longitude=jump_lon, position_covariance_type=known)
        jump.header.stamp = t0 + rospy.Duration(3)  # keyframe 3's
        for f in bad + [jump, good, good]:  # the good one twice: one fix per keyframe
            f.header.stamp = f.header.stamp if f is jump else last
            f.header.frame_id = "gps" if f is good else "base_link"
            f.position_covariance = good.position_covariance
            fixes.publish(f)

        # Awaited: the optimisation publishes keyframe 4 again, moved.
        deadline = time.time() + 30
        moved = None
        while time.time() < deadline and moved is None:
            with recorder.lock:
                for p in recorder.poses:
                    lateral = in_keyframe_axes(p.pose.pose.position)[1]
                    if abs((p.header.stamp - last).to_sec()) < 1e-6 and lateral > by + 0.1:
                        moved = p
            time.sleep(0.05)
        self.assertIsNotNone(moved, "keyframe_pose of keyframe 4 never moved toward the fix")
        mx, my = in_keyframe_axes(moved.pose.pose.position)
        want = predicted_fraction()
        frac = (my - by) / (0.0 - by)
        print("keyframe 4 after the fix: (%.3f, %.3f): moved %.3f of the way, predicted %.3f" % (mx, my, frac, want))
        self.assertLess(math.hypot(mx - 8.0, my), math.hypot(bx - 8.0, by))
        # Along the leg the fix agrees with the odometry once the antenna's 1.0 m forward is taken off
        # (left on, keyframe 4 would move about 0.8 m ahead).
        self.assertAlmostEqual(mx, 8.0, delta=0.1)
        self.assertAlmostEqual(frac, want, delta=0.1)
        # keyframe_fix of that publication: nearer the good fix than before, on the earth too.
        deadline = time.time() + 10
        after_fix = None
        while time.time() < deadline and after_fix is None:
            with recorder.lock:
                near = [f for f in recorder.fixes if abs((f.header.stamp - last).to_sec()) < 1e-6]
                if near and abs(near[-1].latitude - before_fix.latitude) > 1e-9:
                    after_fix = near[-1]
            time.sleep(0.05)
        self.assertIsNotNone(after_fix, "keyframe_fix of keyframe 4 never moved")

        def metres(f):
            return math.hypot((f.latitude - lat) * 111e3, (f.longitude - lon) * 111e3 * math.cos(math.radians(lat)))
        print("keyframe_fix from the good fix: %.3f m before, %.3f m after" % (metres(before_fix), metres(after_fix)))
        self.assertLess(metres(after_fix), 0.5 * metres(before_fix))

        values = backend_values(lambda v: int(v.get("fixes_used", 0)) >= 1 and
                                     int(v.get("fixes_refused_not_finite", 0)) >= 1 and
                                     int(v.get("fixes_refused_keyframe_has_fix", 0)) >= 1 and
                                     int(v.get("fixes_refused_outlier", 0)) >= 1)
        self.assertIsNotNone(values, "no back-end status on /diagnostics")
        for key, n in (("fixes_used", 1), ("fixes_refused_no_fix", 1), ("fixes_refused_not_finite", 1),
                       ("fixes_refused_keyframe_has_fix", 1), ("fixes_refused_outlier", 1),
                       ("fixes_refused_no_keyframe", 0),
                       ("fixes_refused_no_datum", 0), ("fixes_waiting", 0)):
            self.assertEqual(int(values[key]), n, "%s: %s" % (key, values))


if __name__ == "__main__":
    rospy.init_node("check_fix_input")
    rostest.rosrun("uw_multislam", "fix_input", FixInputTest)
