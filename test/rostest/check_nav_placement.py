#!/usr/bin/python3
"""rostest: a piece after a tracking loss is placed by the nav, live, so `map` does not jump.

Session a of the nav prior's mission (test/nav_blackout_survey.yaml: frames 8..37 blank, the
vehicle's dead reckoning on /nav/odom at make_survey's default 1 % drift) through slam.launch with
slam/nav/on_tracking_loss new_session: the black-out ends the first piece although the nav is
there, and the first textured frame after it starts a second one. Each frame's nav reading,
camera_info, altitude and image are published in turn (the nav first), waiting for each frame's
odometry pose; automatic joins are off (slam/backend/join_min_loops 0), so only the placement can
put the two pieces in one map.
- ~case place (nav.place_pieces, the default): the second piece's keyframe 0 carries the nav's
  placement (Keyframe placement_*: the first piece, one of its keyframes, a covariance from the
  nav's drift); the back-end puts the piece in the first piece's map at that keyframe
  (nav_placements 1, one map): keyframe_pose, in `map`, is where the ground truth puts the vehicle
  in the first piece's frame within 3 sigma of the placement, far from the new piece's origin.
- ~case off (place_pieces false): no placement, two maps, and keyframe_pose jumps to the new
  piece's origin (what the placement removes).
- ~case new_session (the odometry's ~nav_world_fixed: the nav's frame does not reset between
  sessions): the frames before the black-out are session 0; then start_session, and the black-out
  and the frames after it go to the new session (no tracking loss: the new session's odometry
  starts at the first textured frame), the nav continuous across both. The new session's keyframe
  0 carries the nav's placement against session 0's last keyframe with a reading (the two
  readings' errors independent), the back-end puts it in session 0's map at once and keyframe_pose
  is where the truth puts the vehicle within 3 sigma, as in case place.
- ~case new_session_off (~nav_world_fixed unset, the default): the same flight, no placement, a
  new map, keyframe_pose at the new session's origin.
"""
import csv
import math
import os
import shutil
import threading
import unittest

import rospy
import rostest
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import CameraInfo, Image, Range
from pipeline_fixture import (NS, SENSOR_TOPICS, appender, await_condition, bag_frames, compose, connected,
                              DiagnosticsWatch, invert, make_mission, mount_of_params, vehicle_from_camera)
from uw_multislam.msg import Keyframe
from uw_multislam.msg import SessionState, Status
from uw_multislam.srv import ListSessions, StartSession

BLACKOUT = range(8, 38)  # frames 8..37 of session a
with open(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "nav_blackout_survey.yaml")) as _f:
    MISSION = _f.read()
assert "{first_frame: %d, num_frames: %d, kind: blank}" % (BLACKOUT.start, len(BLACKOUT)) in MISSION
TOPICS = SENSOR_TOPICS + ["/nav/odom"]


class NavPlacementTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.case = rospy.get_param("~case", "place")
        cls.tmp, cls.mission = make_mission("uwms_nav_placement_", MISSION)

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def test_nav_placement_case(self):
        lock = threading.RLock()
        keyframes, poses, keyframe_poses = [], [], []

        subs = [rospy.Subscriber(NS + "/keyframes", Keyframe, appender(lock, keyframes), queue_size=1000),
                rospy.Subscriber(NS + "/odometry/pose", PoseWithCovarianceStamped, appender(lock, poses),
                                 queue_size=1000),
                rospy.Subscriber(NS + "/keyframe_pose", PoseWithCovarianceStamped, appender(lock, keyframe_poses),
                                 queue_size=1000),
                DiagnosticsWatch(("odometry", "backend"), lock)]
        status = subs[-1].values  # status name -> its newest values
        pubs = [rospy.Publisher(t, m, queue_size=100) for t, m in zip(TOPICS, (Image, CameraInfo, Range, Odometry))]
        await_condition(lock, lambda: connected(pubs) and "odometry" in status and "backend" in status, 60,
                        "the odometry's subscriptions and diagnostics")
        frames = bag_frames(os.path.join(self.mission, "a.bag"), TOPICS)
        frame_of = {}  # image stamp -> frame index
        new_session = self.case.startswith("new_session")
        started = None  # start_session's new session (cases new_session*)
        for i, (image, info, altitude, nav) in enumerate(frames):
            if new_session and i == BLACKOUT.start:
                started = self.start_session(lock)
            frame_of[image.header.stamp] = i
            pubs[3].publish(nav)
            pubs[2].publish(altitude)
            pubs[1].publish(info)
            pubs[0].publish(image)
            stamp = image.header.stamp
            await_condition(lock, lambda: any(p.header.stamp == stamp for p in poses) or
                            status["odometry"].get("frames_finished", 0) >= len(frame_of), 30,
                            "frame %d finished" % i, lambda: ": %s" % status.get("odometry"))
        await_condition(lock, lambda: status["odometry"].get("frames_finished") == len(frames) and
                        status["backend"].get("keyframes_received") == len(keyframes) and
                        status["backend"].get("queue_length") == 0, 60, "every keyframe in the back-end",
                        lambda: ": %s" % status)
        for s in subs:
            s.unregister()
        with lock:
            odometry, backend = dict(status["odometry"]), dict(status["backend"])
            keyframes, keyframe_poses = list(keyframes), list(keyframe_poses)

        self.assertEqual(odometry["frames_with_nav"], len(frames), "every frame with its nav reading")
        if new_session:
            self.assertEqual(odometry["tracking_losses"], 0, "start_session, not the black-out, ends session 0")
        else:
            self.assertEqual(odometry["tracking_losses"], 1, "the black-out ends the first piece")
        first, second = keyframes[0].session, None
        for k in keyframes:
            if k.session != first:
                second = k
                break
        self.assertIsNotNone(second, "a second piece")
        if new_session:
            self.assertEqual(second.session, started, "the second piece is start_session's")
            self.assertLess(frame_of[[k for k in keyframes if k.session == first][-1].header.stamp], BLACKOUT.start)
        self.assertEqual(second.keyframe, 0)
        start = frame_of[second.header.stamp]
        self.assertGreaterEqual(start, BLACKOUT.stop, "the second piece starts after the black-out")
        rospy.wait_for_service(NS + "/list_sessions", timeout=30)
        listed = rospy.ServiceProxy(NS + "/list_sessions", ListSessions)().sessions
        maps = {s.session: s.map for s in listed}
        # keyframe_pose when the second piece's first keyframe came: the vehicle in `map`.
        at_start = [p for p in keyframe_poses if p.header.stamp == second.header.stamp]
        self.assertTrue(at_start, "keyframe_pose for the second piece's first keyframe")
        pose = at_start[0].pose.pose.position

        if self.case in ("off", "new_session_off"):
            self.assertEqual(backend["nav_placements"], 0)
            if second.placement_visual:
                # The odometry's own registration across the black-out (a visual bridge), not the nav's:
                # only after a tracking loss, against the first piece, and it joins the two maps.
                self.assertEqual(self.case, "off", "a visual bridge follows a tracking loss only")
                self.assertEqual(second.placement_session, first)
                self.assertEqual(maps[first], maps[second.session], "the bridge joins the maps")
                return
            self.assertEqual(second.placement_session, -1)
            self.assertEqual(second.placement_keyframe, -1)
            self.assertEqual(list(second.placement_covariance), [0.0] * 9)
            self.assertEqual(backend["nav_placements"], 0)
            self.assertNotEqual(maps[first], maps[second.session], "two maps without the placement")
            self.assertLess(math.hypot(pose.x, pose.y), 1e-6, "the map jumps to the new piece's origin")
            return

        # The placement the odometry sent: against the first piece, from the nav's drift.
        self.assertEqual(second.placement_session, first)
        placed_from = [k for k in keyframes if k.session == first and k.keyframe == second.placement_keyframe]
        self.assertEqual(len(placed_from), 1, "the placement names a keyframe of the first piece")
        self.assertLess(frame_of[placed_from[0].header.stamp], BLACKOUT.start, "a keyframe that saw the seabed")
        sigma = math.sqrt(second.placement_covariance[0])
        if new_session:  # the last keyframe of session 0 (each carries its reading)
            self.assertEqual(second.placement_keyframe, max(k.keyframe for k in keyframes if k.session == first))
        self.assertAlmostEqual(second.placement_covariance[4], second.placement_covariance[0])
        self.assertGreater(sigma, 0.005, "more than the nav prior's floor: the drift over the black-out")
        self.assertEqual(backend["nav_placements"], 1)
        self.assertEqual(backend["maps"], 1)
        self.assertEqual(maps[first], maps[second.session], "one map from the second piece's first keyframe")

        # Where the ground truth puts the vehicle in the first piece's frame (its frame 0).
        with open(os.path.join(self.mission, "world_gt.csv")) as f:
            world = {int(r["index"]): (float(r["x_m"]), float(r["y_m"]), float(r["yaw_rad"]))
                     for r in csv.DictReader(f) if r["session"] == "0"}
        origin = frame_of[keyframes[0].header.stamp]
        truth = vehicle_from_camera(compose(invert(world[origin]), world[start]), mount_of_params())
        error = math.hypot(pose.x - truth[0], pose.y - truth[1])
        rospy.loginfo("the second piece (frame %d) placed %.1f cm from the truth, placement sigma %.1f cm, "
                      "%.2f m from its own origin", start, error * 100, sigma * 100, math.hypot(pose.x, pose.y))
        self.assertLessEqual(error, 3 * sigma)
        self.assertGreater(math.hypot(truth[0], truth[1]), 3 * sigma, "at the new piece's origin it would fail")

    def start_session(self, lock):
        """start_session, and the back-end's active_session naming the new session (which the odometry
        takes at its next frame). Returns the new session's id."""
        announced = []
        sub = rospy.Subscriber(NS + "/active_session", SessionState, appender(lock, announced), queue_size=10)
        rospy.wait_for_service(NS + "/start_session", timeout=30)
        res = rospy.ServiceProxy(NS + "/start_session", StartSession)("second")
        self.assertEqual(res.status.code, Status.OK, res.status.message)
        await_condition(lock, lambda: any(m.session == res.session and m.state == SessionState.ACTIVE
                                          for m in announced), 30, "active_session naming session %d" % res.session)
        sub.unregister()
        return res.session


if __name__ == "__main__":
    rospy.init_node("check_nav_placement")
    rostest.rosrun("uw_multislam", "nav_placement", NavPlacementTest)
