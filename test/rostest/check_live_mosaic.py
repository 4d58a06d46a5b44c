#!/usr/bin/python3
"""rostest: the back-end's live mosaic (topic mosaic) and its export service.

The two-session mission of pipeline_fixture is played (automatic joining off). The mosaic's size
is checked against the active map's keyframe footprints computed here from the published paths
(base_link = the camera with the default mount), the keyframes' altitudes and cameras (Keyframe
messages) and the configured resolution; after join_sessions the map holds both sessions and the
mosaic follows. export writes the files of a session or map below ~export_root; an unknown
session is NOT_FOUND, a folder outside the root (.., absolute, a symbolic link out)
INVALID_ARGUMENT, and nothing is created outside.
"""
import math
import os
import shutil
import subprocess
import tempfile
import threading
import time
import unittest

import rospy
import rostest
from pipeline_fixture import NS, SENSOR_TOPICS, await_condition, make_mission, wait_for_subscribers, wait_until_quiet
from nav_msgs.msg import Path
from sensor_msgs.msg import Image
from uw_multislam.msg import Keyframe, Loop, Status
from uw_multislam.srv import ExportSurvey, JoinSessions, ListSessions


class LiveMosaicTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp, cls.mission = make_mission("uwms_live_mosaic_")
        cls.lock = threading.Lock()
        cls.paths, cls.keyframes, cls.mosaics = {}, {}, []
        cls.last_message = time.time()

        def on_path(session):
            def callback(msg):
                with cls.lock:
                    cls.paths[session] = msg
            return callback

        def on_keyframe(msg):
            with cls.lock:
                cls.keyframes[(msg.session, msg.keyframe)] = msg
                cls.last_message = time.time()

        def on_loop(_):
            with cls.lock:
                cls.last_message = time.time()

        def on_mosaic(msg):
            with cls.lock:
                cls.mosaics.append((time.time(), msg))

        cls.subs = [rospy.Subscriber(NS + "/paths/session_0", Path, on_path(0)),
                    rospy.Subscriber(NS + "/paths/session_1", Path, on_path(1)),
                    rospy.Subscriber(NS + "/keyframes", Keyframe, on_keyframe, queue_size=1000),
                    rospy.Subscriber(NS + "/loops", Loop, on_loop, queue_size=1000),
                    rospy.Subscriber(NS + "/mosaic", Image, on_mosaic, queue_size=10)]
        for srv in ("join_sessions", "list_sessions", "export"):
            rospy.wait_for_service(NS + "/" + srv, timeout=60)
        cls.join = rospy.ServiceProxy(NS + "/join_sessions", JoinSessions)
        cls.list = rospy.ServiceProxy(NS + "/list_sessions", ListSessions)
        cls.export = rospy.ServiceProxy(NS + "/export", ExportSurvey)
        cls.root = rospy.get_param(NS + "/backend_node/export_root")
        cls.resolution = rospy.get_param(NS + "/backend_node/mosaic_resolution")
        wait_for_subscribers(["/camera/image_raw", NS + "/keyframes", NS + "/loops"], "/check_live_mosaic")
        for name in ("s0", "s1"):
            subprocess.run(["rosbag", "play", "-q", "--wait-for-subscribers", "-d", "1", "-r", "4",
                            os.path.join(cls.mission, name + ".bag"),
                            "--topics"] + SENSOR_TOPICS, check=True, timeout=120)
            wait_until_quiet(cls.lock, lambda: cls.last_message, 5.0)

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)
        shutil.rmtree(cls.root, ignore_errors=True)

    def expected_size(self, sessions):
        """(width, height) in pixels of the union of the sessions' keyframe footprints (whole
        camera images at their altitudes) at the configured resolution, and the keyframe count.
        Called under self.lock. The footprint is written out independently of the core: pixel
        edges (-0.5 .. w - 0.5) x (-0.5 .. h - 0.5) around (cx, cy), scaled by altitude / f,
        rotated by the keyframe's yaw in image axes (the path's z-up pose: (x, -y, -yaw))."""
        xs, ys, n = [], [], 0
        for s in sessions:
            if s not in self.paths:
                return None
            for k, p in enumerate(self.paths[s].poses):
                kf = self.keyframes.get((s, k))
                if kf is None:
                    return None
                q = p.pose.orientation
                x, y, yaw = p.pose.position.x, -p.pose.position.y, -2.0 * math.atan2(q.z, q.w)
                c, sn = math.cos(yaw), math.sin(yaw)
                for u in (-0.5, kf.width - 0.5):
                    for v in (-0.5, kf.height - 0.5):
                        gx, gy = (u - kf.cx) * kf.altitude_m / kf.fx, (v - kf.cy) * kf.altitude_m / kf.fy
                        xs.append(x + c * gx - sn * gy)
                        ys.append(y + sn * gx + c * gy)
                n += 1
        res = self.resolution
        return math.ceil((max(xs) - min(xs)) / res), math.ceil((max(ys) - min(ys)) / res), n

    def size_matches(self, msg, sessions):
        expected = self.expected_size(sessions)
        return expected is not None and abs(msg.width - expected[0]) <= 1 and abs(msg.height - expected[1]) <= 1

    def state(self, sessions):
        def describe():
            last = self.mosaics[-1][1] if self.mosaics else None
            return "; last mosaic %s, expected %s" % (
                (last.width, last.height) if last else None, self.expected_size(sessions))
        return describe

    def test_1_the_mosaic_has_the_active_maps_extent(self):
        # Session 1 is active and alone in its map (no automatic join).
        await_condition(self.lock, lambda: self.mosaics and self.size_matches(self.mosaics[-1][1], [1]), 30.0,
                        "a mosaic of session 1's map at %.3f m/px" % self.resolution, self.state([1]))
        with self.lock:
            msg = self.mosaics[-1][1]
            expected = self.expected_size([1])
        self.assertEqual(msg.encoding, "bgr8")
        self.assertEqual(msg.header.frame_id, "map")
        self.assertGreater(expected[2], 5)  # keyframes of session 1
        # The images are drawn: most of the raster is covered (the loop is a closed track).
        data = bytearray(msg.data)
        covered = sum(1 for i in range(0, len(data), 3) if data[i] or data[i + 1] or data[i + 2])
        self.assertGreater(covered, 0.3 * msg.width * msg.height)
        # The active keyframe is outlined in pure red (the drawn images are grey thumbnails).
        red = sum(1 for i in range(0, len(data), 3) if data[i] == 0 and data[i + 1] == 0 and data[i + 2] == 255)
        self.assertGreater(red, 10)

    def test_2_the_mosaic_changes_after_a_join(self):
        with self.lock:
            before = self.mosaics[-1][1] if self.mosaics else None
        self.assertIsNotNone(before)
        called = time.time()
        res = self.join(0, 1, 3)
        self.assertEqual(res.status.code, Status.OK, res.status.message)
        self.assertEqual(res.map, 0)
        await_condition(
            self.lock, lambda: any(t > called and self.size_matches(m, [0, 1]) for t, m in self.mosaics), 30.0,
            "a mosaic of map 0 (sessions 0 and 1) after the join", self.state([0, 1]))
        with self.lock:
            after = [m for t, m in self.mosaics if t > called][-1]
        self.assertNotEqual((after.width, after.height, bytes(after.data)),
                            (before.width, before.height, bytes(before.data)))
        self.assertGreater(after.width * after.height, before.width * before.height)

    def sessions(self):
        res = self.list()
        self.assertEqual(res.status.code, Status.OK)
        return [(s.session, s.name, s.state, s.map, s.num_keyframes, s.num_loops) for s in res.sessions]

    def test_3_export_writes_the_files_below_the_root(self):
        res = self.export(session="0", map=True, folder="dive/products", origin="", resolution_m=0.02,
                          no_mosaic=False)
        self.assertEqual(res.status.code, Status.OK, res.status.message)
        root = os.path.realpath(self.root)
        self.assertEqual(res.directory, os.path.join(root, "dive", "products"))
        names = sorted(os.path.basename(f) for f in res.files)
        self.assertEqual(names, sorted("map_0." + e for e in ("tum", "kitti", "csv", "g2o", "png", "pgw")))
        for f in res.files:
            self.assertTrue(os.path.isfile(f) and os.path.getsize(f) > 0, f)
        with self.lock:
            keyframes = len(self.paths[0].poses) + len(self.paths[1].poses)
        with open(os.path.join(res.directory, "map_0.tum")) as f:
            rows = [line for line in f if line.strip() and not line.startswith("#")]
        self.assertEqual(len(rows), keyframes)  # the joined map: both sessions
        # A session by name, tracks only, with an origin: GeoJSON too.
        res = self.export(session="session_1", map=False, folder="", origin="-33.84,151.25,90", resolution_m=0.0,
                          no_mosaic=True)
        self.assertEqual(res.status.code, Status.OK, res.status.message)
        self.assertEqual(sorted(os.path.basename(f) for f in res.files),
                         sorted("session_1." + e for e in ("tum", "kitti", "csv", "g2o", "geojson")))

    def test_4_wrong_exports_are_refused_and_change_nothing(self):
        before = self.sessions()
        outside = tempfile.mkdtemp(prefix="uwms_outside_")
        try:
            os.symlink(outside, os.path.join(self.root, "link_out"))
            cases = [("nope", "x_unknown", Status.NOT_FOUND, "nope"),
                     ("0", "../escaped", Status.INVALID_ARGUMENT, "outside the export root"),
                     ("0", "a/../../escaped", Status.INVALID_ARGUMENT, "outside the export root"),
                     ("0", outside, Status.INVALID_ARGUMENT, "outside the export root"),
                     ("0", "link_out/deeper", Status.INVALID_ARGUMENT, "outside the export root")]
            for session, folder, code, said in cases:
                res = self.export(session=session, map=False, folder=folder, origin="", resolution_m=0.0,
                                  no_mosaic=True)
                self.assertEqual(res.status.code, code, "%s %s: %s" % (session, folder, res.status.message))
                self.assertIn(said, res.status.message)
                self.assertEqual(list(res.files), [])
            res = self.export(session="0", map=False, folder="", origin="north", resolution_m=0.0, no_mosaic=True)
            self.assertEqual(res.status.code, Status.INVALID_ARGUMENT, res.status.message)
            self.assertEqual(os.listdir(outside), [])
            self.assertFalse(os.path.exists(os.path.join(os.path.dirname(os.path.realpath(self.root)), "escaped")))
            self.assertFalse(os.path.exists(os.path.join(self.root, "x_unknown")))
        finally:
            shutil.rmtree(outside, ignore_errors=True)
        self.assertEqual(self.sessions(), before)


if __name__ == "__main__":
    rospy.init_node("check_live_mosaic")
    rostest.rosrun("uw_multislam", "check_live_mosaic", LiveMosaicTest)
