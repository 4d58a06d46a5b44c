#!/usr/bin/python3
"""rostest set_datum: the back-end's set_datum service, checked with check_datum.py's WGS84, UTM
and compass arithmetic (independent of GeographicLib and of the back-end's rotation). One back-end
on a fresh session store with ~datum/* (43.0951, 5.9307, heading 30, utm frame): two keyframes
come out in ENU for heading 30 (keyframe_pose, the path, then `pose` and map -> odom from an
odometry pose); bad values and a second datum without `replace` are refused with earth -> map
unchanged; with `replace` (heading 0, 3 m above the ellipsoid) earth -> map (ENU, no heading turn),
map -> utm and keyframe_fix follow the new datum, and without a new keyframe the path,
keyframe_pose, map -> session_0 and map -> odom are published again in the new axes (heading 0:
the first keyframe's x axis is north, 1 m along it is (0, 1)); the same datum again is OK, unchanged.
Then the back-end is stopped and started again with the same parameters: the store's datum is the
one in use, and the log says so."""
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import unittest

import rospy
import rostest
import tf2_ros

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from check_datum import (NS, LAT, LON, HEADING, KEYFRAME_1, Recorder, check_keyframe_1_in_enu,  # noqa: E402
                         datum_frame, geodetic, in_enu, rotate, send_two_keyframes, utm, yaw_of)
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped  # noqa: E402
from nav_msgs.msg import Path  # noqa: E402
from pipeline_fixture import tool  # noqa: E402
from uw_multislam.msg import Status  # noqa: E402
from uw_multislam.srv import SetDatum, SetDatumRequest  # noqa: E402

NEW = (43.1012, 5.9421, 0.0, 3.0)  # lat, lon, heading (the first keyframe's x axis north), alt: set at sea


class Backend(object):
    """backend_node in NS, its output kept."""

    def __init__(self, store):
        rospy.set_param(NS + "/backend_node", {"store_path": store, "export_root": "", "datum": {
            "latitude_deg": LAT, "longitude_deg": LON, "heading_deg": HEADING, "utm_frame": "utm"}})
        self.node = subprocess.Popen([tool("backend_node"), "__ns:=" + NS, "__name:=backend_node"],
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        self.lines = []
        threading.Thread(target=lambda: self.lines.extend(self.node.stdout), daemon=True).start()
        rospy.wait_for_service(NS + "/set_datum", timeout=60)

    def stop(self):
        self.node.send_signal(signal.SIGINT)
        self.node.wait(timeout=60)
        return self.node.returncode

    def kill(self):
        if self.node.poll() is None:
            self.node.kill()
            self.node.wait()


def request(lat, lon, heading=None, alt=0.0, replace=False):
    return SetDatumRequest(latitude_deg=lat, longitude_deg=lon, altitude_m=alt, with_heading=heading is not None,
                           heading_deg=heading if heading is not None else 0.0, replace=replace)


class LastPath(object):
    """paths/session_0 (latched) as it comes."""

    def __init__(self):
        self.lock = threading.Lock()
        self.paths = []
        self.sub = rospy.Subscriber(NS + "/paths/session_0", Path, self.keep)

    def keep(self, msg):
        with self.lock:
            self.paths.append(msg)

    def await_last_pose_at(self, east, north, timeout=30.0):
        """Awaits a path whose last pose is at (east, north) to 1 um; fails with what came."""
        deadline = time.time() + timeout
        while time.time() < deadline:
            with self.lock:
                for p in self.paths:
                    q = p.poses[-1].pose.position if p.poses else None
                    if q and abs(q.x - east) < 1e-6 and abs(q.y - north) < 1e-6 and p.header.frame_id == "map":
                        return
            time.sleep(0.05)
        with self.lock:
            got = [(p.poses[-1].pose.position.x, p.poses[-1].pose.position.y) for p in self.paths if p.poses]
        raise AssertionError("no paths/session_0 ending at (%.4f, %.4f): %s" % (east, north, got))


class Odometry(object):
    """The odometry's part: odometry/pose sent as the vehicle 1 m along session 0's x axis (its first
    keyframe's image columns), the back-end's `pose` kept."""

    def __init__(self):
        self.lock = threading.Lock()
        self.poses = []
        self.pub = rospy.Publisher(NS + "/odometry/pose", PoseWithCovarianceStamped, queue_size=10)
        self.sub = rospy.Subscriber(NS + "/pose", PoseStamped, self.keep)

    def keep(self, msg):
        with self.lock:
            self.poses.append(msg)

    def await_pose_at(self, east, north, timeout=30.0):
        """Sends odometry/pose every 0.2 s until the back-end's `pose` is at (east, north) in map,
        facing along the same axis; fails with the last one."""
        deadline = time.time() + timeout
        while time.time() < deadline:
            m = PoseWithCovarianceStamped()
            m.header.stamp = rospy.Time.now()
            m.header.frame_id = "session_0"
            m.pose.pose.position.x = 1.0
            m.pose.pose.orientation.w = 1.0
            m.pose.covariance = [0.01 if i % 7 == 0 else 0.0 for i in range(36)]
            self.pub.publish(m)
            time.sleep(0.2)
            with self.lock:
                last = self.poses[-1] if self.poses else None
            if last is not None:
                p, q = last.pose.position, last.pose.orientation
                if (abs(p.x - east) < 1e-6 and abs(p.y - north) < 1e-6 and last.header.frame_id == "map" and
                        abs(yaw_of((q.x, q.y, q.z, q.w)) - math.atan2(north, east)) < 1e-9):
                    return
        raise AssertionError("pose never at (%.4f, %.4f): last %s" % (east, north, last))


def map_to_odom_yaw_is(test, buffer, yaw, timeout=10.0):
    """Awaits map -> odom at the origin turned by `yaw` (odom is session 0's frame here)."""
    deadline = time.time() + timeout
    while True:
        t = buffer.lookup_transform("map", "odom", rospy.Time(0), rospy.Duration(timeout)).transform
        got = yaw_of((t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w))
        if abs(got - yaw) < 1e-9 and abs(t.translation.x) < 1e-9 and abs(t.translation.y) < 1e-9:
            return
        if time.time() > deadline:
            test.fail("map -> odom %s (yaw %.6f), expected yaw %.6f" % (t, got, yaw))
        time.sleep(0.05)


class SetDatumTest(unittest.TestCase):
    def earth_to_map_is(self, buffer, datum, timeout=30.0):
        """Awaits earth -> map at `datum` (lat, lon, heading, alt): origin to 1 mm, axes to 1e-9
        east, north, up (map is ENU: the heading does not turn it)."""
        origin, x_axis, y_axis, up = datum_frame(datum[0], datum[1], 90.0, datum[3])
        deadline = time.time() + timeout
        while True:
            t = buffer.lookup_transform("earth", "map", rospy.Time(0), rospy.Duration(timeout)).transform
            q = (t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w)
            got = (t.translation.x, t.translation.y, t.translation.z)
            errors = [max(abs(got[i] - origin[i]) for i in range(3)) / 1e-3] + [
                max(abs(rotate(q, axis)[i] - expected[i]) for i in range(3)) / 1e-9
                for axis, expected in (((1.0, 0.0, 0.0), x_axis), ((0.0, 1.0, 0.0), y_axis), ((0.0, 0.0, 1.0), up))]
            if max(errors) <= 1.0:
                return
            if time.time() > deadline:
                self.fail("earth -> map %s, %s is not the datum %s (ECEF %s)" % (got, q, datum, origin))
            time.sleep(0.05)

    def test_set_datum(self):
        tmp = tempfile.mkdtemp(prefix="uwms_set_datum_")
        store = os.path.join(tmp, "sessions.db")
        backend = Backend(store)
        try:
            buffer = tf2_ros.Buffer()
            tf2_ros.TransformListener(buffer)
            call = rospy.ServiceProxy(NS + "/set_datum", SetDatum)
            self.earth_to_map_is(buffer, (LAT, LON, HEADING, 0.0))
            # Two keyframes with the parameters' datum: in ENU for heading 30.
            recorder = Recorder()
            recorder.connect(with_fix=True)
            path = LastPath()
            last = send_two_keyframes()
            pair = recorder.at(last, with_fix=True)
            self.assertIsNotNone(pair, "no keyframe_pose and keyframe_fix of keyframe 1")
            check_keyframe_1_in_enu(self, pair[0], HEADING)
            path.await_last_pose_at(*in_enu(KEYFRAME_1[0], KEYFRAME_1[1], HEADING))
            # The vehicle 1 m along the first keyframe's columns, at heading 30: (sin 30, cos 30) in map.
            odometry = Odometry()
            odometry.await_pose_at(*in_enu(1.0, 0.0, HEADING))
            map_to_odom_yaw_is(self, buffer, math.radians(90.0 - HEADING))
            # Refused, nothing changed: each bad value named.
            for req, key in ((request(float("nan"), LON), "latitude_deg nan is not a number"),
                             (request(91.0, LON), "latitude_deg 91 is outside [-90, 90]"),
                             (request(LAT, LON, heading=float("inf")), "heading_deg inf is not a number"),
                             (request(LAT, LON, alt=float("nan"), replace=True), "altitude_m nan"),
                             (request(85.0, LON, replace=True), "outside UTM")):
                res = call(req)
                self.assertEqual(res.status.code, Status.INVALID_ARGUMENT, res.status.message)
                self.assertIn(key, res.status.message)
                self.assertIn("43.0951000, 5.9307000, 0.00 m, first keyframe's x axis heading 30.0 deg", res.datum)
            res = call(request(*NEW[:2], heading=NEW[2], alt=NEW[3]))
            self.assertEqual(res.status.code, Status.ALREADY_EXISTS, res.status.message)
            self.assertIn("43.0951000, 5.9307000", res.status.message)
            self.assertIn("replace: true", res.status.message)
            self.earth_to_map_is(buffer, (LAT, LON, HEADING, 0.0), timeout=0.0)  # still the parameters'
            # Moved with replace: tf, the poses and keyframe_fix follow, without a new keyframe.
            with recorder.lock:
                del recorder.poses[:], recorder.fixes[:]
            res = call(request(*NEW[:2], heading=NEW[2], alt=NEW[3], replace=True))
            self.assertEqual(res.status.code, Status.OK, res.status.message)
            self.assertIn("kept in the session store", res.note)
            self.assertEqual(res.datum, "43.1012000, 5.9421000, 3.00 m, first keyframe's x axis heading 0.0 deg")
            self.earth_to_map_is(buffer, NEW)
            # Heading 0: the first keyframe's columns point north, its rows east: keyframe 1 at (25, 40).
            east, north = in_enu(KEYFRAME_1[0], KEYFRAME_1[1], NEW[2])
            self.assertAlmostEqual(east, 25.0, delta=1e-12)
            self.assertAlmostEqual(north, 40.0, delta=1e-12)
            path.await_last_pose_at(east, north)
            s0 = buffer.lookup_transform("map", "session_0", rospy.Time(0), rospy.Duration(10.0)).transform
            self.assertAlmostEqual(yaw_of((s0.rotation.x, s0.rotation.y, s0.rotation.z, s0.rotation.w)), math.pi / 2,
                                   delta=1e-9)  # session 0's x axis (its first keyframe's columns) north
            map_to_odom_yaw_is(self, buffer, math.pi / 2)
            # 1 m along the first keyframe's columns is 1 m north: (0, 1) in map.
            self.assertEqual(tuple(round(v, 12) for v in in_enu(1.0, 0.0, NEW[2])), (0.0, 1.0))
            odometry.await_pose_at(*in_enu(1.0, 0.0, NEW[2]))
            zone, easting, northing, gamma = utm(NEW[0], NEW[1])
            t = buffer.lookup_transform("utm", "map", rospy.Time(0), rospy.Duration(10.0)).transform
            self.assertAlmostEqual(t.translation.x, easting, delta=1e-3)
            self.assertAlmostEqual(t.translation.y, northing, delta=1e-3)
            self.assertAlmostEqual(t.translation.z, NEW[3], delta=1e-9)
            b = math.radians(90.0 - gamma)  # map's x axis east: only the grid convergence turns it
            x_axis = rotate((t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w), (1.0, 0.0, 0.0))
            for got, expected in zip(x_axis, (math.sin(b), math.cos(b), 0.0)):
                self.assertAlmostEqual(got, expected, delta=1e-9)
            pair = recorder.at(last, with_fix=True)
            self.assertIsNotNone(pair, "keyframe_pose and keyframe_fix of keyframe 1 not published again")
            pose, fix = pair
            check_keyframe_1_in_enu(self, pose, NEW[2])
            x, y = pose.pose.pose.position.x, pose.pose.pose.position.y
            origin, xa, ya, _ = datum_frame(NEW[0], NEW[1], 90.0, NEW[3])
            lat, lon, height = geodetic(tuple(origin[i] + x * xa[i] + y * ya[i] for i in range(3)))
            print("keyframe 1 at map (%.3f, %.3f): fix %.9f, %.9f, %.4f m; expected %.9f, %.9f, %.4f m" %
                  (x, y, fix.latitude, fix.longitude, fix.altitude, lat, lon, height))
            self.assertAlmostEqual(fix.latitude, lat, delta=1e-9)  # 0.1 mm on the ground
            self.assertAlmostEqual(fix.longitude, lon, delta=1e-9)
            self.assertAlmostEqual(fix.altitude, height, delta=1e-4)
            # ENU: the fix's covariance is keyframe_pose's (x, y) block unturned.
            c = pose.pose.covariance
            for got, expected in zip(fix.position_covariance[:5], (c[0], c[1], 0.0, c[6], c[7])):
                self.assertAlmostEqual(got, expected, delta=1e-12 + 1e-9 * abs(expected))
            res = call(request(*NEW[:2], heading=NEW[2], alt=NEW[3]))
            self.assertEqual(res.status.code, Status.OK, res.status.message)
            self.assertIn("unchanged", res.note)
            self.assertEqual(backend.stop(), 0, "".join(backend.lines))
            # A restart with the same ~datum/*: the store's datum is used, and said so.
            backend = Backend(store)
            buffer = tf2_ros.Buffer()  # a new listener hears only the new back-end's /tf_static
            tf2_ros.TransformListener(buffer)
            self.earth_to_map_is(buffer, NEW)
            self.assertEqual(call(request(*NEW[:2], heading=NEW[2], alt=NEW[3])).status.code, Status.OK)
            warned = [line for line in backend.lines if "is used, not ~datum/* parameters'" in line]
            self.assertEqual(len(warned), 1, "".join(backend.lines))
            self.assertEqual(backend.stop(), 0, "".join(backend.lines))
        finally:
            backend.kill()
            rospy.delete_param(NS + "/backend_node")
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    rospy.init_node("check_set_datum")
    rostest.rosrun("uw_multislam", "set_datum", SetDatumTest)
