#!/usr/bin/python3
"""rostest: the equivalence of the two heads of the one engine. A generated two-session mission
played through slam.launch (odometry, loop detection in one nodelet or split into two, the
back-end / session manager) gives the keyframes, loops (with their measured poses and
covariances), links, session ids, maps and trajectories that offline_slam computes from the same
data, to 1e-6 (what the CSV files' 6 decimals resolve).

The bags are generated at test time (make_survey, small images) in a temporary directory and
played one after the other with rosbag play; the second session's stamps start 1000 s after the
first's, so the odometry starts session 1 by its stamp gap rule. offline_slam runs the same core
on the dataset folders. Both run with backend.optimise false, so that the loop nodelet's local-loop
candidates come from the odometry chain (the back-end then publishes the odometry's poses), as
offline_slam's do; test/rostest/check_backend.py covers the optimising back-end.
"""
import csv
import os
import shutil
import subprocess
import threading
import time
import unittest

import rosgraph
import rospy
import rostest
from pipeline_fixture import (NS, SENSOR_TOPICS, SURVEY, DiagnosticsWatch, chain_covariance, make_mission, matmul3,
                              planar_covariance, status_values, tool, vehicle_from_camera, wait_for_subscribers,
                              wait_until_quiet, connected)
import rosnode
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path
from uw_multislam.srv import ListSessions
from sensor_msgs.msg import CameraInfo, Image, Range
from uw_multislam.msg import Keyframe, KeyframeHash, Loop

PLAY_RATE = 4.0  # 4 frames per second: far below the odometry's speed on these 240 x 180 images
TOLERANCE = 1e-6  # metres and radians: the same computation on the same pixels
# The altimeter travels as a float32 Range; the dataset folder keeps it as decimal text. Altitudes
# exact in both (no noise, 1.625 and 1.75 m) make the two heads see the same numbers; with 4-decimal
# noisy altitudes the float32 rounding alone moves the joined session by a few micrometres.
EXACT_SURVEY = (SURVEY.replace("altitude_m: 1.6,", "altitude_m: 1.625,").replace("altitude_m: 1.7,", "altitude_m: 1.75,")
                .replace("  - name: s0\n", "  - name: s0\n    altimeter_noise_m: 0\n")
                .replace("  - name: s1\n", "  - name: s1\n    altimeter_noise_m: 0\n"))
assert EXACT_SURVEY.count("altimeter_noise_m: 0") == 2 and "1.625" in EXACT_SURVEY and "1.75" in EXACT_SURVEY



def read_csv(path):
    with open(path) as f:
        return list(csv.DictReader(f))


class SlamPipelineTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp, out = make_mission("uwms_pipeline_", EXACT_SURVEY)
        cls.bags = [os.path.join(out, "s0.bag"), os.path.join(out, "s1.bag")]
        # The reference: offline_slam on the same folders, local loops from the odometry chain.
        with open(os.path.join(cls.tmp, "slam.yaml"), "w") as f:
            f.write("backend: {optimise: false}\n")
            f.write("odometry: {features: {type: %s}}\n" % rospy.get_param("~features", "sift"))
        run = os.path.join(cls.tmp, "run")
        subprocess.run([tool("offline_slam"), "--session", os.path.join(out, "s0"), "--session",
                        os.path.join(out, "s1"), "--out", run, "--config", os.path.join(cls.tmp, "slam.yaml"),
                        "--quiet"], check=True, timeout=300)
        cls.expected_keyframes = [(int(r["session"]), int(r["index"]), float(r["x_m"]), float(r["y_m"]))
                                  for r in read_csv(os.path.join(run, "odometry.csv"))]
        cls.expected_loops = {(int(r["session_a"]), int(r["index_a"]), int(r["session_b"]), int(r["index_b"]),
                               r["kind"]) for r in read_csv(os.path.join(run, "loops.csv"))}
        cls.expected_loop_poses = {(int(r["session_a"]), int(r["index_a"]), int(r["session_b"]), int(r["index_b"])): r
                                   for r in read_csv(os.path.join(run, "loop_poses.csv"))}
        cls.expected_trajectory = read_csv(os.path.join(run, "trajectory.csv"))
        cls.expected_links = read_csv(os.path.join(run, "links.csv"))

        cls.lock = threading.Lock()
        cls.keyframes, cls.loops, cls.hashes, cls.poses, cls.odoms = [], [], [], [], []
        cls.last_message = time.time()

        def keep(store):
            def callback(msg):
                with cls.lock:
                    store.append(msg)
                    cls.last_message = time.time()
            return callback

        cls.subs = [rospy.Subscriber(NS + "/keyframes", Keyframe, keep(cls.keyframes), queue_size=1000),
                    rospy.Subscriber(NS + "/loops", Loop, keep(cls.loops), queue_size=1000),
                    rospy.Subscriber(NS + "/keyframe_hashes", KeyframeHash, keep(cls.hashes), queue_size=1000),
                    rospy.Subscriber(NS + "/odometry/pose", PoseWithCovarianceStamped, keep(cls.poses),
                                     queue_size=1000),
                    rospy.Subscriber(NS + "/odom", Odometry, keep(cls.odoms), queue_size=1000)]
        wait_for_subscribers(SENSOR_TOPICS + [NS + "/keyframes"], "/check_slam_pipeline")
        for bag in cls.bags:
            subprocess.run(["rosbag", "play", "-q", "--wait-for-subscribers", "-d", "1", "-r",
                            str(rospy.get_param("~play_rate", PLAY_RATE)), bag,
                            "--topics",
                            "/camera/image_raw", "/camera/camera_info", "/altitude"], check=True, timeout=120)
            wait_until_quiet(cls.lock, lambda: cls.last_message, 5.0)

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)
        store = rospy.get_param("~store_path", "")
        for suffix in ("", "-wal", "-shm", ".lock"):  # live_paging's store (a new file per run)
            if store and os.path.exists(store + suffix):
                os.remove(store + suffix)

    def test_keyframes_of_both_sessions_match_offline_slam(self):
        got = [(k.session, k.frame_index, k.odometry_pose.x, k.odometry_pose.y) for k in self.keyframes]
        self.assertEqual([g[:2] for g in got], [e[:2] for e in self.expected_keyframes])
        self.assertGreaterEqual(len([g for g in got if g[0] == 1]), 8)
        for g, e in zip(got, self.expected_keyframes):
            self.assertAlmostEqual(g[2], e[2], delta=TOLERANCE, msg="x of keyframe %s" % (g[:2],))
            self.assertAlmostEqual(g[3], e[3], delta=TOLERANCE, msg="y of keyframe %s" % (g[:2],))

    def test_odometry_covariances_are_the_cores(self):
        """odometry/pose at each keyframe: the keyframes' motion covariances composed (written out in
        Python), turned z-up (F = diag(1, -1, -1), the default mount). odom (nav_msgs/Odometry) at the
        same stamp: that pose placed in the odom frame, where session 0 is odom's origin and later
        sessions are rotated in (the covariance keeps its trace and determinant)."""
        poses = {p.header.stamp: p for p in self.poses}
        odoms = {o.header.stamp: o for o in self.odoms}
        f = [[1, 0, 0], [0, -1, 0], [0, 0, -1]]
        checked = 0
        for session in (0, 1):
            kfs = [k for k in self.keyframes if k.session == session]
            chain = [(k.odometry_pose.x, k.odometry_pose.y, k.odometry_pose.theta) for k in kfs]
            covs = [[list(k.motion_covariance[3 * r:3 * r + 3]) for r in range(3)] for k in kfs]
            for n in range(2, len(kfs) + 1):
                expected = matmul3(matmul3(f, chain_covariance(chain[:n], covs[:n])), f)
                pose = poses.get(kfs[n - 1].header.stamp)
                if pose is None:
                    continue  # not every pose message need arrive (queue), most do
                got = planar_covariance(pose.pose.covariance)
                scale = max(abs(v) for r in expected for v in r)
                for i in range(3):
                    for j in range(3):
                        self.assertAlmostEqual(got[i][j], expected[i][j], delta=1e-9 * scale,
                                               msg="odometry/pose covariance, session %d keyframe %d" % (session, n - 1))
                odom = odoms.get(kfs[n - 1].header.stamp)
                self.assertIsNotNone(odom, "no odom message at keyframe %d of session %d" % (n - 1, session))
                self.assertEqual((odom.header.frame_id, odom.child_frame_id), ("odom", "base_link"))
                o = planar_covariance(odom.pose.covariance)
                if session == 0:
                    self.assertAlmostEqual(odom.pose.pose.position.x, pose.pose.pose.position.x, delta=1e-9)
                    self.assertAlmostEqual(odom.pose.pose.position.y, pose.pose.pose.position.y, delta=1e-9)
                    self.assertEqual(o, got)
                self.assertAlmostEqual(o[0][0] + o[1][1], got[0][0] + got[1][1], delta=1e-9 * scale)
                self.assertAlmostEqual(o[0][0] * o[1][1] - o[0][1] ** 2, got[0][0] * got[1][1] - got[0][1] ** 2,
                                       delta=1e-9 * scale * scale)
                self.assertAlmostEqual(o[2][2], got[2][2], delta=1e-12 * scale)
                checked += 1
        print("odometry/pose and odom covariances checked at %d keyframes" % checked)
        self.assertGreater(checked, 15)

    def test_loop_measurements_match_offline_slam(self):
        """Each loop's measured pose of b in a and its covariance, as offline_slam measured them."""
        self.assertEqual(len(self.loops), len(self.expected_loop_poses))
        for l in self.loops:
            e = self.expected_loop_poses[(l.session_a, l.frame_a, l.session_b, l.frame_b)]
            for got, key in ((l.pose.x, "x_m"), (l.pose.y, "y_m"), (l.pose.theta, "yaw_rad")):
                self.assertAlmostEqual(got, float(e[key]), delta=TOLERANCE, msg="%s of loop %s" % (key, e))
            cov = [float(e[k]) for k in ("cov_xx", "cov_xy", "cov_xyaw", "cov_yy", "cov_yyaw", "cov_yawyaw")]
            got_cov = [l.covariance[i] for i in (0, 1, 2, 4, 5, 8)]
            for g, c in zip(got_cov, cov):
                self.assertAlmostEqual(g, c, delta=1e-6 * max(1.0, abs(c)) + 1e-12, msg="covariance of loop %s" % e)

    def test_sessions_maps_links_and_trajectories_match_offline_slam(self):
        """The back-end's sessions (ids, maps) and its paths in the map frame, as offline_slam's
        trajectory.csv and links.csv say."""
        listed = rospy.ServiceProxy(NS + "/list_sessions", ListSessions)()
        self.assertEqual(listed.status.code, 0)
        expected_maps = {int(r["session"]): int(r["map"]) for r in self.expected_trajectory}
        self.assertEqual({s.session: s.map for s in listed.sessions}, expected_maps)
        self.assertEqual(len(self.expected_links), 1, "the fixture's two sessions join into one map")
        for session in sorted(expected_maps):
            path = rospy.wait_for_message(NS + "/paths/session_%d" % session, Path, timeout=10)
            rows = [r for r in self.expected_trajectory if int(r["session"]) == session]
            self.assertEqual(len(path.poses), len(rows))
            for p, r in zip(path.poses, rows):
                # The path gives base_link in the z-up map; the file the camera in image axes.
                x, y, _ = vehicle_from_camera((float(r["x_m"]), float(r["y_m"]), float(r["yaw_rad"])))
                self.assertAlmostEqual(p.pose.position.x, x, delta=TOLERANCE, msg=str(r))
                self.assertAlmostEqual(p.pose.position.y, y, delta=TOLERANCE, msg=str(r))

    def test_keyframes_are_complete(self):
        per_session = {}
        for k in self.keyframes:
            per_session.setdefault(k.session, []).append(k.keyframe)
            n = len(k.u_px)
            self.assertGreater(n, 100)
            width = 32 if rospy.get_param("~features", "sift") == "orb" else 128  # ORB's 256 bits, SIFT's 128 bytes
            self.assertEqual(k.descriptor_size, width)
            self.assertEqual(len(k.descriptors), width * n)
            self.assertEqual((k.width, k.height), (240, 180))
            self.assertAlmostEqual(k.fx, 220.0)
            self.assertGreater(k.altitude_m, 1.4)
            self.assertEqual(k.status, Keyframe.FIRST if k.keyframe == 0 else Keyframe.MATCHED)
            if k.keyframe > 0:
                self.assertGreater(k.motion_covariance[0], 0.0)
                self.assertGreater(k.inliers, 20)
        self.assertEqual(sorted(per_session), [0, 1])
        for ids in per_session.values():
            self.assertEqual(ids, list(range(len(ids))))
        self.assertGreater(len(self.poses), len(self.keyframes))
        self.assertEqual({p.header.frame_id for p in self.poses}, {"session_0", "session_1"})

    def test_loops_local_and_global_match_offline_slam(self):
        got = {(l.session_a, l.frame_a, l.session_b, l.frame_b, "local" if l.kind == Loop.LOCAL else "global")
               for l in self.loops}
        kinds = [g[4] for g in got]
        rospy.loginfo("loops: %d local, %d global (offline_slam: %d)", kinds.count("local"), kinds.count("global"),
                      len(self.expected_loops))
        self.assertGreaterEqual(kinds.count("local"), 5)
        self.assertGreaterEqual(kinds.count("global"), 5)
        self.assertEqual(len(got), len(self.loops), "a loop was published twice")
        self.assertEqual(got, self.expected_loops)
        for l in self.loops:
            self.assertGreaterEqual(l.inliers, 20)  # loops.*.min_inliers
            self.assertGreater(l.covariance[0], 0.0)
            if l.kind == Loop.GLOBAL:
                self.assertNotEqual(l.session_a, l.session_b)
            else:
                self.assertEqual(l.session_a, l.session_b)

    def test_live_keyframes_are_paged_out_only_with_a_store(self):
        """live_paging:=true: with a session store and page_live_after 3 the
        loop detector pages out its live keyframes 3 behind the newest (keyframes_paged_live) and
        reads the candidates among them back from the store (feature_cache_misses), none failed;
        every other test of this suite holds (the same loops as offline_slam). Without a store
        nothing is paged."""
        live = bool(rospy.get_param("~live_paging", False))
        got = status_values("loop_detector", lambda v: "keyframes_paged_live" in v, 30.0) or {}
        self.assertIn("keyframes_paged_live", got, "no loop detector diagnostics")
        paged, misses = int(float(got["keyframes_paged_live"])), int(float(got["feature_cache_misses"]))
        print("live_paging %s: %d live keyframes paged out, %d read back, %s read failures" %
              (live, paged, misses, got.get("feature_read_failures")))
        if live:
            self.assertGreater(paged, len(self.keyframes) // 2)
            self.assertGreater(misses, 0)
        else:
            self.assertEqual(paged, 0)
            self.assertEqual(misses, 0)
        self.assertEqual(int(float(got["feature_read_failures"])), 0)

    def test_frames_are_prepared_ahead_only_when_asked(self):
        """prepare_threads:=2: frames played at 200 per second wait in the
        odometry's FIFO and are prepared ahead (diagnostics prepared_ahead > 0), and every other
        test of this suite holds: the same keyframes, loops and maps as offline_slam. With the
        default 0 none is."""
        threads = int(rospy.get_param("~prepare_threads", 0))
        got = status_values("odometry", lambda v: "prepared_ahead" in v, 30.0, node="odometry_node") or {}
        self.assertIn("prepared_ahead", got, "no odometry diagnostics")
        prepared, frames = int(got["prepared_ahead"]), int(got["frames_processed"])
        print("prepare_threads %d: %d of %d frames prepared ahead" % (threads, prepared, frames))
        if threads > 0:
            self.assertGreater(prepared, 0)
            self.assertLess(prepared, frames)  # the first frame of a burst is never prepared ahead
        else:
            self.assertEqual(prepared, 0)

    def test_each_loop_detector_publishes_its_kind_and_the_back_end_receives_all(self):
        """split_loops:=true end to end: the local detector publishes the local loops and no global
        one, the global detector the global loops and no local one, and the back-end receives every
        loop of both (its joins: test_sessions_maps_links_and_trajectories_match_offline_slam). In
        one detector (split_loops false) it publishes both kinds. From the nodes' diagnostics, once
        their counts reach the loops this test received (or the last seen after 30 s)."""
        split = rospy.get_param("~split_loops")
        with self.lock:
            local = len([l for l in self.loops if l.kind == Loop.LOCAL])
            global_ = len(self.loops) - local
        expected = ({"local_loops_node": ("local", local, 0), "global_loops_node": ("global", 0, global_)} if split
                    else {"loop_detector_node": ("both", local, global_)})

        def done(seen):
            return (all(n in seen and (seen[n]["mode"], int(seen[n]["local_loops"]), int(seen[n]["global_loops"])) == e
                        for n, e in expected.items())
                    and "backend_node" in seen and int(seen["backend_node"]["loops_received"]) == local + global_)

        watch = DiagnosticsWatch(("loop_detector", "backend"), by_node=True)
        try:
            got = watch.await_values(None, done, 30)
        finally:
            watch.unregister()
        self.assertGreaterEqual(local, 5)
        self.assertGreaterEqual(global_, 5)
        for node, (mode, n_local, n_global) in expected.items():
            self.assertIn(node, got, "no diagnostics of %s (seen: %s)" % (node, sorted(got)))
            self.assertEqual((got[node]["mode"], int(got[node]["local_loops"]), int(got[node]["global_loops"])),
                             (mode, n_local, n_global), "%s: mode, local and global loops published" % node)
        self.assertIn("backend_node", got)
        self.assertEqual(int(got["backend_node"]["loops_received"]), local + global_, "loops the back-end received")

    def test_one_hash_per_keyframe(self):
        self.assertEqual([(h.session, h.keyframe) for h in self.hashes],
                         [(k.session, k.keyframe) for k in self.keyframes])
        for h in self.hashes:
            self.assertEqual(len(h.values), 384)
            self.assertEqual(h.hash_mode, KeyframeHash.SORTED_DCT)

    def test_bad_input_is_skipped_without_crashing(self):
        """A float image, an empty image and a camera_info without focal length, each with a NaN
        altitude: skipped (no pose, no keyframe), and the node keeps running."""
        pubs = [rospy.Publisher(t, m, queue_size=10) for t, m in
                (("/camera/image_raw", Image), ("/camera/camera_info", CameraInfo), ("/altitude", Range))]
        deadline = time.time() + 60
        while time.time() < deadline and not connected(pubs):
            time.sleep(0.2)
        # Sent before the odometry's connections, the bad frames would be lost, not counted.
        self.assertTrue(connected(pubs), "the odometry never connected to this test's publishers")
        with self.lock:
            poses_before, keyframes_before = len(self.poses), len(self.keyframes)
        stamp = rospy.Time(1700005000)  # after both sessions
        good_info = CameraInfo(width=240, height=180, K=[220, 0, 119.5, 0, 220, 89.5, 0, 0, 1])
        cases = [(Image(encoding="32FC1", width=240, height=180, step=960, data=bytes(960 * 180)), good_info),
                 (Image(encoding="mono8", width=0, height=0, step=0, data=b""), good_info),
                 (Image(encoding="mono8", width=240, height=180, step=240, data=bytes(range(240)) * 180),
                  CameraInfo(width=240, height=180, K=[0] * 9))]
        watch = DiagnosticsWatch(("odometry",))
        kinds = ("skipped_encoding", "skipped_empty_image", "skipped_camera_info")
        start = watch.await_values("odometry")
        self.assertIsNotNone(start, "no odometry status on /diagnostics")
        for i, (image, info) in enumerate(cases):
            image.header.stamp = info.header.stamp = stamp + rospy.Duration(i)
            altitude = Range(range=float("nan"), min_range=0.1, max_range=100)
            altitude.header.stamp = image.header.stamp
            for p, m in zip(pubs, (image, info, altitude)):
                p.publish(m)
            time.sleep(0.5)
        # Until the odometry has counted each bad frame as skipped (its worker is done with them).
        end = watch.await_values("odometry", lambda v: all(v[k] >= start[k] + 1 for k in kinds), 30)
        watch.unregister()
        self.assertEqual([end[k] - start[k] for k in kinds], [1, 1, 1])
        with self.lock:
            self.assertEqual(len(self.poses), poses_before, "a bad frame was processed")
            self.assertEqual(len(self.keyframes), keyframes_before)
        state = rosgraph.Master("/check_slam_pipeline").getSystemState()
        nodes = dict(state[0]).get(NS + "/odometry/pose", [])
        self.assertTrue(nodes, "nobody publishes the odometry pose any more")
        for node in nodes:
            self.assertTrue(rosnode.rosnode_ping(node, max_count=1), "%s does not answer" % node)


if __name__ == "__main__":
    rospy.init_node("check_slam_pipeline")
    rostest.rosrun("uw_multislam", "check_slam_pipeline", SlamPipelineTest)
