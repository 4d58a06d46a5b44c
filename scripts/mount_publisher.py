#!/usr/bin/python3
"""Publishes where the camera and the altimeter sit on the vehicle as static tf, for a vehicle
without a URDF (Debian has no static_transform_publisher binary). The odometry looks both up from
base_link to the frames its sensors name in their headers (the image's and the Range's
header.frame_id); launch/core.launch starts this script when its camera_mount argument is given.

    mount_publisher.py --camera camera 0.35 -0.15 -0.2 0.4 [--altimeter altimeter 0.1 0.2 -0.2] [--base base_link]

--camera FRAME X Y Z YAW: the camera's optical centre in the base frame (metres; REP-103: x forward,
    y port, z up) and the yaw of its image columns from the base frame's x (rad). FRAME is its
    optical frame (x along the image columns, z down the optical axis): the camera looks straight
    down (the 2-D model refuses a camera tilted more than frames/max_camera_tilt_deg).
--altimeter FRAME X Y Z: the altimeter in the base frame (its orientation: the base frame's).
--base: the base frame; default the parameter frames/base_frame of this node's namespace, else base_link.
"""
import argparse
import math
import sys

import rospy
import tf2_ros
from geometry_msgs.msg import TransformStamped


def transform(base, child, xyz, quaternion_xyzw, stamp):
    t = TransformStamped()
    t.header.stamp = stamp
    t.header.frame_id = base
    t.child_frame_id = child
    t.transform.translation.x, t.transform.translation.y, t.transform.translation.z = xyz
    q = t.transform.rotation
    q.x, q.y, q.z, q.w = quaternion_xyzw
    return t


def camera_rotation(yaw):
    """The optical frame: the level frame (yaw about z) turned by pi about x, (0, 0, sin, cos) x (1, 0, 0, 0)."""
    return (math.cos(yaw / 2.0), math.sin(yaw / 2.0), 0.0, 0.0)


def finite(values, name, parser):
    for v in values:
        if not math.isfinite(v) or abs(v) >= 1e3:
            parser.error("%s: %r must be finite, |.| < 1000" % (name, v))


def main(argv):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    parser.add_argument("--camera", nargs=5, metavar=("FRAME", "X", "Y", "Z", "YAW"), required=True)
    parser.add_argument("--altimeter", nargs=4, metavar=("FRAME", "X", "Y", "Z"))
    parser.add_argument("--base", default=None)
    args = parser.parse_args(rospy.myargv(argv)[1:])
    try:
        camera = [float(v) for v in args.camera[1:]]
        altimeter = [float(v) for v in args.altimeter[1:]] if args.altimeter else None
    except ValueError as e:
        parser.error(str(e))
    finite(camera, "--camera", parser)
    if altimeter:
        finite(altimeter, "--altimeter", parser)
    rospy.init_node("mount_publisher")
    base = args.base or rospy.get_param("frames/base_frame", "base_link")
    if base in (args.camera[0], args.altimeter[0] if args.altimeter else None):
        parser.error("the sensor frames must differ from the base frame %s" % base)
    stamp = rospy.Time.now()
    transforms = [transform(base, args.camera[0], camera[:3], camera_rotation(camera[3]), stamp)]
    if altimeter:
        transforms.append(transform(base, args.altimeter[0], altimeter, (0.0, 0.0, 0.0, 1.0), stamp))
    broadcaster = tf2_ros.StaticTransformBroadcaster()
    broadcaster.sendTransform(transforms)  # latched: every later listener gets them
    rospy.loginfo("mount_publisher: %s", "; ".join(
        "%s -> %s at (%.3f, %.3f, %.3f)" % (base, t.child_frame_id, t.transform.translation.x,
                                           t.transform.translation.y, t.transform.translation.z)
        for t in transforms) + ", camera yaw %.3f rad" % camera[3])
    rospy.spin()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
