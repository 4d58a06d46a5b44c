#!/usr/bin/python3
"""rostest: the back-end's datum (datum.test), checked with plain WGS84 and UTM arithmetic written
here (independent of GeographicLib, which the back-end uses). `map` is ENU at the datum (REP-103),
whatever the datum's heading (the compass heading of the first keyframe's x axis):
1. the static earth -> map is the datum's ECEF position and its east/north/up axes, no heading turn;
2. the static map -> utm puts map's origin at the datum's UTM easting/northing (Krueger's series)
   with map's x axis (east) at grid bearing 90 degrees less the grid convergence;
3. keyframe_pose is in ENU: keyframe 1 (40 m along the first keyframe's image columns, 25 m along
   its rows) where the heading puts it, its covariance turned with it; keyframe_fix is its position
   on WGS84 (through earth -> map, then ECEF -> geodetic) with its (x, y) covariance as east/north.
Without a datum (datum.test datum:=false): keyframe_pose comes, keyframe_fix is not advertised; and a
second back-end given a polar datum with a UTM frame refuses to start, naming ~datum/utm_frame."""
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
from geometry_msgs.msg import PoseWithCovarianceStamped
from sensor_msgs.msg import NavSatFix, NavSatStatus

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from pipeline_fixture import connected, tool  # noqa: E402
from uw_multislam.msg import Keyframe  # noqa: E402

NS = "/uw_multislam"
WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
E2 = WGS84_F * (2 - WGS84_F)
LAT, LON, HEADING = 43.0951, 5.9307, 30.0  # datum.test's parameters


def rotate(q, v):
    """v turned by the unit quaternion q (x, y, z, w)."""
    x, y, z, w = q
    # v + 2 w (u x v) + 2 u x (u x v), u = (x, y, z)
    ux = (y * v[2] - z * v[1], z * v[0] - x * v[2], x * v[1] - y * v[0])
    uux = (y * ux[2] - z * ux[1], z * ux[0] - x * ux[2], x * ux[1] - y * ux[0])
    return tuple(v[i] + 2 * w * ux[i] + 2 * uux[i] for i in range(3))


def datum_frame(lat=LAT, lon=LON, heading=HEADING, alt=0.0):
    """ECEF origin and map's x, y, z axes in ECEF, from the datum (alt: the origin's height)."""
    phi, lam, h = math.radians(lat), math.radians(lon), math.radians(heading)
    n = WGS84_A / math.sqrt(1 - E2 * math.sin(phi) ** 2)
    origin = ((n + alt) * math.cos(phi) * math.cos(lam), (n + alt) * math.cos(phi) * math.sin(lam),
              (n * (1 - E2) + alt) * math.sin(phi))
    east = (-math.sin(lam), math.cos(lam), 0.0)
    north = (-math.sin(phi) * math.cos(lam), -math.sin(phi) * math.sin(lam), math.cos(phi))
    up = (math.cos(phi) * math.cos(lam), math.cos(phi) * math.sin(lam), math.sin(phi))
    # map's x axis has compass heading h; y is 90 degrees anticlockwise of it (z up).
    x_axis = tuple(math.sin(h) * east[i] + math.cos(h) * north[i] for i in range(3))
    y_axis = tuple(-math.cos(h) * east[i] + math.sin(h) * north[i] for i in range(3))
    return origin, x_axis, y_axis, up


def in_enu(x_img, y_img, heading_deg, cov=None):
    """A point x_img along the first keyframe's image columns and y_img along its rows, as
    (east, north) when those columns point at compass heading h (the image is seen from above, the
    camera looking down: the rows point 90 degrees clockwise of the columns, at heading h + 90);
    with `cov` (3x3 over x_img, y_img and the yaw from columns towards rows), also that covariance
    in (east, north, ENU yaw), where a turn towards the rows is clockwise: the ENU yaw falls."""
    h = math.radians(heading_deg)
    cols, rows = (math.sin(h), math.cos(h)), (math.sin(h + math.pi / 2), math.cos(h + math.pi / 2))
    en = tuple(x_img * cols[i] + y_img * rows[i] for i in range(2))
    if cov is None:
        return en
    m = ((cols[0], rows[0], 0.0), (cols[1], rows[1], 0.0), (0.0, 0.0, -1.0))
    return en, [[sum(m[i][a] * cov[a][b] * m[j][b] for a in range(3) for b in range(3)) for j in range(3)]
                for i in range(3)]


def yaw_of(q):
    """The yaw (about z) of a z-up quaternion (x, y, z, w)."""
    x, y, z, w = q
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


KEYFRAME_1 = (40.0, 25.0, 0.3)  # send_two_keyframes' keyframe 1 in the first keyframe's image axes
KEYFRAME_1_COV = ((0.04, 0.01, 0.0), (0.01, 0.09, 0.0), (0.0, 0.0, 0.001))


def geodetic(p):
    """ECEF -> (lat, lon, height), Bowring's start and a fixed-point iteration on the latitude."""
    x, y, z = p
    lon = math.atan2(y, x)
    r = math.hypot(x, y)
    lat = math.atan2(z, r * (1 - E2))
    for _ in range(10):
        n = WGS84_A / math.sqrt(1 - E2 * math.sin(lat) ** 2)
        h = r / math.cos(lat) - n
        lat = math.atan2(z, r * (1 - E2 * n / (n + h)))
    n = WGS84_A / math.sqrt(1 - E2 * math.sin(lat) ** 2)
    return math.degrees(lat), math.degrees(lon), r / math.cos(lat) - n


def utm(lat_deg, lon_deg):
    """(zone, easting, northing, convergence in degrees) by Krueger's series to n^4 (sub-mm in a
    zone); the convergence is the bearing of grid north clockwise from true north."""
    zone = int((lon_deg + 180.0) // 6) + 1
    lon0 = math.radians((zone - 1) * 6 - 180 + 3)
    phi, dlam = math.radians(lat_deg), math.radians(lon_deg) - lon0
    n = WGS84_F / (2 - WGS84_F)
    big_a = WGS84_A / (1 + n) * (1 + n ** 2 / 4 + n ** 4 / 64)
    alpha = (n / 2 - 2 * n ** 2 / 3 + 5 * n ** 3 / 16 + 41 * n ** 4 / 180,
             13 * n ** 2 / 48 - 3 * n ** 3 / 5 + 557 * n ** 4 / 1440,
             61 * n ** 3 / 240 - 103 * n ** 4 / 140,
             49561 * n ** 4 / 161280)
    c = 2 * math.sqrt(n) / (1 + n)
    t = math.sinh(math.atanh(math.sin(phi)) - c * math.atanh(c * math.sin(phi)))
    xi_p = math.atan2(t, math.cos(dlam))
    eta_p = math.atanh(math.sin(dlam) / math.sqrt(1 + t * t))
    xi, eta, sigma, tau = xi_p, eta_p, 1.0, 0.0
    for j, a in enumerate(alpha, start=1):
        xi += a * math.sin(2 * j * xi_p) * math.cosh(2 * j * eta_p)
        eta += a * math.cos(2 * j * xi_p) * math.sinh(2 * j * eta_p)
        sigma += 2 * j * a * math.cos(2 * j * xi_p) * math.cosh(2 * j * eta_p)
        tau += 2 * j * a * math.sin(2 * j * xi_p) * math.sinh(2 * j * eta_p)
    k0 = 0.9996
    easting = 500000.0 + k0 * big_a * eta
    northing = k0 * big_a * xi + (0.0 if lat_deg >= 0 else 10000000.0)
    s = math.sqrt(1 + t * t)
    gamma = math.atan2(tau * s + sigma * t * math.tan(dlam), sigma * s - tau * t * math.tan(dlam))
    return zone, easting, northing, math.degrees(gamma)


def send_two_keyframes():
    """Session 0's keyframe 0 and keyframe 1 (40 m along, 25 m across, with a covariance) to the
    back-end; returns keyframe 1's stamp."""
    keyframes = rospy.Publisher(NS + "/keyframes", Keyframe, queue_size=10)
    deadline = time.time() + 45
    while time.time() < deadline and not connected([keyframes]):
        time.sleep(0.1)
    if not connected([keyframes]):
        raise AssertionError("the back-end never connected to this test's keyframes")
    stamp = rospy.Time.now()
    for index, motion, cov in ((0, (0.0, 0.0, 0.0), [0.0] * 9),
                               (1, KEYFRAME_1, [c for row in KEYFRAME_1_COV for c in row])):
        k = Keyframe(session=0, keyframe=index, frame_index=index, altitude_m=2.0, width=240, height=180, fx=220,
                     fy=220, cx=119.5, cy=89.5, descriptor_size=128,
                     status=Keyframe.FIRST if index == 0 else Keyframe.MATCHED)
        k.header.stamp = stamp + rospy.Duration(index)
        k.motion.x, k.motion.y, k.motion.theta = motion
        k.odometry_pose.x, k.odometry_pose.y, k.odometry_pose.theta = motion
        k.motion_covariance = cov
        keyframes.publish(k)
    return stamp + rospy.Duration(1)


class Recorder(object):
    """keyframe_pose and keyframe_fix as they come."""

    def __init__(self):
        self.lock = threading.Lock()
        self.poses, self.fixes = [], []
        self.subscribers = [rospy.Subscriber(NS + "/keyframe_pose", PoseWithCovarianceStamped, self.keep(self.poses)),
                            rospy.Subscriber(NS + "/keyframe_fix", NavSatFix, self.keep(self.fixes))]

    def keep(self, into):
        def callback(msg):
            with self.lock:
                into.append(msg)
        return callback

    def connect(self, with_fix, timeout=45.0):
        """Awaits the back-end's connections to keyframe_pose (and keyframe_fix): neither is latched."""
        subscribers = self.subscribers if with_fix else self.subscribers[:1]
        deadline = time.time() + timeout
        while time.time() < deadline and not all(s.get_num_connections() > 0 for s in subscribers):
            time.sleep(0.1)
        if not all(s.get_num_connections() > 0 for s in subscribers):
            raise AssertionError("the back-end's keyframe_pose%s never connected" % (" or keyframe_fix" * with_fix))

    def at(self, stamp, with_fix, timeout=30.0):
        """The last keyframe_pose of `stamp` (and keyframe_fix, with_fix), awaited; None on time-out."""
        # The back-end keeps stamps as double seconds: equal to well under a microsecond, not to the ns.
        def near(m):
            return abs((m.header.stamp - stamp).to_sec()) < 1e-6

        deadline = time.time() + timeout
        while time.time() < deadline:
            with self.lock:
                poses = [p for p in self.poses if near(p)]
                fixes = [f for f in self.fixes if near(f)]
            if poses and (fixes or not with_fix):
                # keyframe_fix goes out right after keyframe_pose, with the same stamp.
                return poses[-1], fixes[-1] if fixes else None
            time.sleep(0.05)
        return None


def check_keyframe_1_in_enu(test, pose, heading_deg):
    """keyframe_pose of send_two_keyframes' keyframe 1 is where a datum of `heading_deg` puts it in
    ENU (in_enu), its yaw and its x, y, yaw covariance turned with it."""
    p = pose.pose.pose
    (east, north), cov = in_enu(KEYFRAME_1[0], KEYFRAME_1[1], heading_deg, KEYFRAME_1_COV)
    facing = in_enu(math.cos(KEYFRAME_1[2]), math.sin(KEYFRAME_1[2]), heading_deg)
    yaw = yaw_of((p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w))
    print("keyframe 1 in map (%.4f, %.4f, yaw %.4f); in ENU at heading %.1f: (%.4f, %.4f, yaw %.4f)" %
          (p.position.x, p.position.y, yaw, heading_deg, east, north, math.atan2(facing[1], facing[0])))
    test.assertEqual(pose.header.frame_id, "map")
    test.assertAlmostEqual(p.position.x, east, delta=1e-6)
    test.assertAlmostEqual(p.position.y, north, delta=1e-6)
    turn = yaw - math.atan2(facing[1], facing[0])
    test.assertAlmostEqual(math.atan2(math.sin(turn), math.cos(turn)), 0.0, delta=1e-9)
    c = pose.pose.covariance  # 6x6 row-major over x, y, z, roll, pitch, yaw
    for (i, j), k in (((0, 0), 0), ((0, 1), 1), ((1, 1), 7), ((0, 2), 5), ((1, 2), 11), ((2, 2), 35)):
        test.assertAlmostEqual(c[k], cov[i][j], delta=1e-12 + 1e-9 * abs(cov[i][j]),
                               msg="covariance [%d][%d]: %s, expected %s" % (i, j, list(c), cov))


class NoDatumTest(unittest.TestCase):
    def test_a_polar_datum_with_a_utm_frame_stops_the_backend_naming_the_key(self):
        """A second back-end, datum at latitude 85 (UTM ends at 84) with ~datum/utm_frame: one FATAL
        line naming the key, given before the store is opened (its file is not created); the node
        stays up, inert, and SIGINT ends it cleanly."""
        ns = "/bad_datum"
        tmp = tempfile.mkdtemp(prefix="uwms_bad_datum_")
        store = os.path.join(tmp, "sessions.db")
        rospy.set_param(ns + "/backend_node", {"store_path": store, "export_root": "",
                                               "datum": {"latitude_deg": 85.0, "longitude_deg": 10.0,
                                                         "utm_frame": "utm"}})
        node = subprocess.Popen([tool("backend_node"), "__ns:=" + ns, "__name:=backend_node"],
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        lines = []
        reader = threading.Thread(target=lambda: lines.extend(node.stdout), daemon=True)
        reader.start()
        try:
            deadline = time.time() + 60
            while time.time() < deadline and node.poll() is None and not any("not starting" in l for l in lines):
                time.sleep(0.1)
            fatal = [l for l in lines if "not starting" in l]
            self.assertEqual(len(fatal), 1, "".join(lines))
            self.assertIn(ns + "/backend_node/datum/utm_frame: ", fatal[0])
            self.assertIn("outside UTM", fatal[0])
            self.assertFalse(os.path.exists(store), "the store was opened before the datum was refused")
            self.assertIsNone(node.poll(), "the node died:\n" + "".join(lines))
            node.send_signal(signal.SIGINT)
            node.wait(timeout=60)
        finally:
            rospy.delete_param(ns + "/backend_node")
            if node.poll() is None:
                node.kill()
                node.wait()
            shutil.rmtree(tmp, ignore_errors=True)
        self.assertEqual(node.returncode, 0, "".join(lines))

    def test_without_a_datum_keyframe_fix_is_not_advertised(self):
        recorder = Recorder()
        recorder.connect(with_fix=False)
        last = send_two_keyframes()
        got = recorder.at(last, with_fix=False)
        self.assertIsNotNone(got, "no keyframe_pose of keyframe 1 (stamp %s)" % last)
        # map is the first keyframe's frame, z up: the x axis along its image columns (as at heading 90).
        check_keyframe_1_in_enu(self, got[0], 90.0)
        # The back-end advertises keyframe_fix (with a datum) before it subscribes to keyframes, so
        # by now the master would list it.
        topics = [name for name, _ in rospy.get_published_topics()]
        self.assertIn(NS + "/keyframe_pose", topics)
        self.assertNotIn(NS + "/keyframe_fix", topics)
        self.assertEqual(recorder.fixes, [])


class DatumTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.buffer = tf2_ros.Buffer()
        cls.listener = tf2_ros.TransformListener(cls.buffer)
        cls.recorder = Recorder()

    def test_1_earth_to_map_is_the_datum_enu(self):
        # Awaited: the latched /tf_static arrives once the back-end is up.
        t = self.buffer.lookup_transform("earth", "map", rospy.Time(0), rospy.Duration(45.0)).transform
        origin, x_axis, y_axis, up = datum_frame(heading=90.0)  # x east: no turn for the heading
        got = (t.translation.x, t.translation.y, t.translation.z)
        for i in range(3):
            self.assertAlmostEqual(got[i], origin[i], delta=1e-3, msg="ECEF origin %s vs %s" % (got, origin))
        axes = {(1.0, 0.0, 0.0): x_axis, (0.0, 1.0, 0.0): y_axis, (0.0, 0.0, 1.0): up}
        q = (t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w)
        for axis, expected in axes.items():
            turned = rotate(q, axis)
            for i in range(3):
                self.assertAlmostEqual(turned[i], expected[i], delta=1e-9, msg="map axis %s: %s vs %s" %
                                       (axis, turned, expected))

    def test_2_utm_to_map_is_the_datum_in_its_zone(self):
        # utm is map's child (map's parent is earth), so this is map's pose in utm either way round.
        t = self.buffer.lookup_transform("utm", "map", rospy.Time(0), rospy.Duration(45.0)).transform
        zone, easting, northing, gamma = utm(LAT, LON)
        self.assertEqual(zone, 31)
        print("datum in UTM 31N: %.3f E, %.3f N, convergence %.5f deg" % (easting, northing, gamma))
        self.assertAlmostEqual(t.translation.x, easting, delta=1e-3)
        self.assertAlmostEqual(t.translation.y, northing, delta=1e-3)
        self.assertAlmostEqual(t.translation.z, 0.0, delta=1e-9)
        # map's x axis (east): grid bearing 90 - gamma, i.e. (sin b, cos b) in (easting, northing).
        b = math.radians(90.0 - gamma)
        q = (t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w)
        x_axis = rotate(q, (1.0, 0.0, 0.0))
        for got, expected in zip(x_axis, (math.sin(b), math.cos(b), 0.0)):
            self.assertAlmostEqual(got, expected, delta=1e-9, msg="map x in utm %s, grid bearing %.6f deg" %
                                   (x_axis, math.degrees(b)))
        self.assertAlmostEqual(rotate(q, (0.0, 0.0, 1.0))[2], 1.0, delta=1e-12)

    def test_3_keyframe_fix_is_keyframe_pose_on_wgs84(self):
        self.recorder.connect(with_fix=True)
        last = send_two_keyframes()
        pair = self.recorder.at(last, with_fix=True)
        self.assertIsNotNone(pair, "no keyframe_pose and keyframe_fix of keyframe 1 (stamp %s): %d poses, %d fixes" %
                             (last, len(self.recorder.poses), len(self.recorder.fixes)))
        pose, fix = pair
        x, y = pose.pose.pose.position.x, pose.pose.pose.position.y
        check_keyframe_1_in_enu(self, pose, HEADING)
        origin, x_axis, y_axis, _ = datum_frame(heading=90.0)
        lat, lon, height = geodetic(tuple(origin[i] + x * x_axis[i] + y * y_axis[i] for i in range(3)))
        print("keyframe 1 at map (%.3f, %.3f): fix %.9f, %.9f, %.4f m; expected %.9f, %.9f, %.4f m" %
              (x, y, fix.latitude, fix.longitude, fix.altitude, lat, lon, height))
        self.assertEqual(fix.header.stamp, pose.header.stamp)  # one publication, one stamp
        self.assertEqual(fix.header.frame_id, "base_link")
        self.assertEqual(fix.status.status, NavSatStatus.STATUS_FIX)
        self.assertEqual(fix.position_covariance_type, NavSatFix.COVARIANCE_TYPE_KNOWN)
        # 1e-9 degrees is 0.1 mm on the ground.
        self.assertAlmostEqual(fix.latitude, lat, delta=1e-9)
        self.assertAlmostEqual(fix.longitude, lon, delta=1e-9)
        self.assertAlmostEqual(fix.altitude, height, delta=1e-4)
        # Covariance: keyframe_pose's (x, y) block (6x6 row-major), already east/north.
        c = pose.pose.covariance
        self.assertGreater(c[0], 0.0)
        expected = [c[0], c[1], 0.0, c[6], c[7], 0.0, 0.0, 0.0, 0.0]
        for i in range(9):
            self.assertAlmostEqual(fix.position_covariance[i], expected[i], delta=1e-12 + 1e-9 * abs(expected[i]),
                                   msg="covariance %s vs %s" % (list(fix.position_covariance), expected))


if __name__ == "__main__":
    rospy.init_node("check_datum")
    with_datum = os.environ.get("UWMS_TEST_DATUM", "true") == "true"
    rostest.rosrun("uw_multislam", "datum_%s" % ("true" if with_datum else "false"),
                   DatumTest if with_datum else NoDatumTest)
