#!/usr/bin/python3
"""rostest: the back-end's static earth -> map from ~datum (datum.test) is the datum's ECEF
position and its east/north/up axes turned by the heading, computed here with plain WGS84
arithmetic (independent of GeographicLib, which the back-end uses)."""
import math
import unittest

import rospy
import rostest
import tf2_ros

WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
LAT, LON, HEADING = 43.0951, 5.9307, 30.0  # datum.test's parameters


def rotate(q, v):
    """v turned by the unit quaternion q (x, y, z, w)."""
    x, y, z, w = q
    # v + 2 w (u x v) + 2 u x (u x v), u = (x, y, z)
    ux = (y * v[2] - z * v[1], z * v[0] - x * v[2], x * v[1] - y * v[0])
    uux = (y * ux[2] - z * ux[1], z * ux[0] - x * ux[2], x * ux[1] - y * ux[0])
    return tuple(v[i] + 2 * w * ux[i] + 2 * uux[i] for i in range(3))


class DatumTest(unittest.TestCase):
    def setUp(self):
        self.buffer = tf2_ros.Buffer()
        self.listener = tf2_ros.TransformListener(self.buffer)

    def test_earth_to_map_is_the_datum(self):
        # Awaited: the latched /tf_static arrives once the back-end is up.
        t = self.buffer.lookup_transform("earth", "map", rospy.Time(0), rospy.Duration(45.0)).transform
        phi, lam, h = math.radians(LAT), math.radians(LON), math.radians(HEADING)
        e2 = WGS84_F * (2 - WGS84_F)
        n = WGS84_A / math.sqrt(1 - e2 * math.sin(phi) ** 2)
        origin = (n * math.cos(phi) * math.cos(lam), n * math.cos(phi) * math.sin(lam),
                  n * (1 - e2) * math.sin(phi))
        got = (t.translation.x, t.translation.y, t.translation.z)
        for i in range(3):
            self.assertAlmostEqual(got[i], origin[i], delta=1e-3, msg="ECEF origin %s vs %s" % (got, origin))
        east = (-math.sin(lam), math.cos(lam), 0.0)
        north = (-math.sin(phi) * math.cos(lam), -math.sin(phi) * math.sin(lam), math.cos(phi))
        up = (math.cos(phi) * math.cos(lam), math.cos(phi) * math.sin(lam), math.sin(phi))
        # map's x axis has compass heading h; y is 90 degrees anticlockwise of it (z up).
        axes = {
            (1.0, 0.0, 0.0): tuple(math.sin(h) * east[i] + math.cos(h) * north[i] for i in range(3)),
            (0.0, 1.0, 0.0): tuple(-math.cos(h) * east[i] + math.sin(h) * north[i] for i in range(3)),
            (0.0, 0.0, 1.0): up,
        }
        q = (t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w)
        for axis, expected in axes.items():
            turned = rotate(q, axis)
            for i in range(3):
                self.assertAlmostEqual(turned[i], expected[i], delta=1e-9, msg="map axis %s: %s vs %s" %
                                       (axis, turned, expected))


if __name__ == "__main__":
    rospy.init_node("check_datum")
    rostest.rosrun("uw_multislam", "datum", DatumTest)
