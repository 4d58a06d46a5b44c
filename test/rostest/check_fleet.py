#!/usr/bin/python3
"""rostest: hash exchange between two vehicles, test/rostest/fleet.test.

Two pipelines, /auv_a and /auv_b, each with its own store, exchange only KeyframeHash messages
(/fleet/hashes). The fixture mission's session s0 is flown by auv_a and s1 by auv_b at the same
time, frame for frame. On each vehicle the other's session must arrive whole (hashes, motions), the
loops between the two must be found (each pair by searching our keyframe against their hashes or
their hash against our keyframes), features must cross only for candidates (at most once per
keyframe, no failure), the maps must not be joined while both record, and must be joined on both
vehicles as soon as auv_a ends its session (auv_b by the session-ended notice), with auv_b's
keyframes where the ground truth puts them in auv_a's session frame and the two vehicles agreeing.
Prints the bandwidth per keyframe: hash only, and with the features asked for.
"""
import csv
import math
import os
import shutil
import subprocess
import threading
import unittest

import rospy
import rostest
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import Path
from sensor_msgs.msg import CameraInfo, Image, Range
from pipeline_fixture import (appender, await_condition, bag_frames, compose, connected, DiagnosticsWatch, invert,
                              make_mission, vehicle_from_camera)
from uw_multislam.msg import Keyframe, SessionState, Status
from uw_multislam.srv import FinishSession, ListSessions

VEHICLES = ("auv_a", "auv_b")
SESSIONS_TOOL = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "src", "tools", "sessions.py")
MAX_ERROR_M = 0.05  # auv_b's keyframes against the ground truth, in auv_a's session frame
MAX_DISAGREEMENT_M = 0.02  # the two vehicles' joined maps against each other


def yaw_of(q):
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


class FleetTest(unittest.TestCase):
    def setUp(self):
        self.tmp, self.mission = make_mission("uwms_fleet_")
        self.lock = threading.RLock()
        self.keyframes = {v: [] for v in VEHICLES}
        self.poses = {v: [] for v in VEHICLES}
        self.diagnostics = {v: DiagnosticsWatch(("odometry", "loop_detector", "backend"), self.lock, namespace=v)
                            for v in VEHICLES}
        self.subs = list(self.diagnostics.values())
        for v in VEHICLES:
            self.subs.append(rospy.Subscriber("/%s/keyframes" % v, Keyframe, appender(self.lock, self.keyframes[v]),
                                              queue_size=1000))
            self.subs.append(rospy.Subscriber("/%s/odometry/pose" % v, PoseWithCovarianceStamped,
                                              appender(self.lock, self.poses[v]), queue_size=1000))

    def tearDown(self):
        for s in self.subs:
            s.unregister()
        shutil.rmtree(self.tmp, ignore_errors=True)
        for key in ("~store_a", "~store_b"):
            path = rospy.get_param(key, "")
            for suffix in ("", "-wal", "-shm"):
                if path and os.path.exists(path + suffix):
                    os.remove(path + suffix)

    def value(self, vehicle, node, key):
        return self.diagnostics[vehicle].get(node).get(key)

    def status(self):
        """{(vehicle, node): its newest values}."""
        with self.lock:  # reentrant: also from await_condition's conditions
            return {(v, node): values for v, w in self.diagnostics.items() for node, values in w.values.items()}

    def player(self, vehicle, bag):
        """The bag's frames, and send(i): frame i published to `vehicle` and its odometry pose awaited."""
        pubs = [rospy.Publisher("/%s/%s" % (vehicle, t), m, queue_size=100)
                for t, m in zip(("camera/image_raw", "camera/camera_info", "altitude"), (Image, CameraInfo, Range))]
        await_condition(self.lock, lambda: connected(pubs), 60, "%s's odometry subscriptions" % vehicle)
        frames = bag_frames(os.path.join(self.mission, bag))

        def send(i):
            image, info, altitude = frames[i]
            pubs[2].publish(altitude)
            pubs[1].publish(info)
            pubs[0].publish(image)
            stamp = image.header.stamp
            await_condition(self.lock, lambda: any(p.header.stamp == stamp for p in self.poses[vehicle]), 30,
                            "%s's odometry pose" % vehicle)
        return frames, send

    def settled(self, vehicle):
        """Every keyframe of `vehicle` and every loop its loop detector found are in its back-end."""
        b = lambda k: self.value(vehicle, "backend", k)
        d = lambda k: self.value(vehicle, "loop_detector", k)
        return (b("keyframes_received") == len(self.keyframes[vehicle]) and
                d("keyframes_received") == len(self.keyframes[vehicle]) and d("queue_length") == 0 and
                b("loops_received") == (d("local_loops") or 0) + (d("global_loops") or 0) and
                b("queue_length") == 0 and b("loops_waiting") == 0)

    def finish(self, vehicle):
        rospy.wait_for_service("/%s/finish_session" % vehicle, timeout=30)
        r = rospy.ServiceProxy("/%s/finish_session" % vehicle, FinishSession)()
        self.assertEqual(r.status.code, Status.OK, r.status.message)

    def sessions(self, vehicle):
        rospy.wait_for_service("/%s/list_sessions" % vehicle, timeout=30)
        return {s.session: s for s in rospy.ServiceProxy("/%s/list_sessions" % vehicle, ListSessions)().sessions}

    def path(self, vehicle, session):
        return rospy.wait_for_message("/%s/paths/session_%d" % (vehicle, session), Path, timeout=30)

    def test_two_vehicles_exchange_hashes_and_join_their_maps_on_both_sides(self):
        state = lambda: ": %s" % self.status()
        await_condition(self.lock, lambda: all((v, "backend") in self.status() for v in VEHICLES), 60,
                        "both back-ends' diagnostics")
        # auv_a starts s0 first, so that the ids are known: its first keyframe opens a session on
        # auv_b, whose odometry is told (active_session's next_session) that its own takes the next id.
        announced = []
        sub = rospy.Subscriber("/auv_b/active_session", SessionState, appender(self.lock, announced), queue_size=10)
        frames_a, send_a = self.player("auv_a", "s0.bag")
        frames_b, send_b = self.player("auv_b", "s1.bag")
        send_a(0)
        await_condition(self.lock, lambda: any(m.next_session >= 1 for m in announced), 30,
                        "auv_b's active_session with next_session 1", lambda: ": %s" % announced)
        sub.unregister()
        # Then both fly at once, frame for frame: two sessions recording side by side on each
        # vehicle, the loops between them waiting for one of them to end.
        for i in range(1, max(len(frames_a), len(frames_b))):
            if i < len(frames_a):
                send_a(i)
            if i - 1 < len(frames_b):
                send_b(i - 1)
        # The odometry publishes a frame's pose before its keyframe message, so the last keyframe may
        # still be on its way when the last pose has come: counts are taken live, once each
        # odometry's own count of keyframes published has reached the test.
        n = lambda v: len(self.keyframes[v])
        await_condition(self.lock, lambda: self.settled("auv_a") and self.settled("auv_b") and
                        all(self.value(v, "odometry", "keyframes") == n(v) for v in VEHICLES) and
                        self.value("auv_b", "backend", "fleet_hashes_received") == n("auv_a") and
                        self.value("auv_a", "backend", "fleet_hashes_received") == n("auv_b") and
                        self.value("auv_b", "loop_detector", "foreign_keyframes") == n("auv_a") and
                        self.value("auv_a", "loop_detector", "foreign_keyframes") == n("auv_b"), 120,
                        "every keyframe and loop on both vehicles", state)
        with self.lock:
            n_a, n_b = n("auv_a"), n("auv_b")
            for v in VEHICLES:
                self.assertTrue(all(k.session == self.keyframes[v][0].session for k in self.keyframes[v]), v)
        self.assertGreater(n_a, 10)
        self.assertGreater(n_b, 10)
        # Both recording: not joined yet on either vehicle.
        listed = {v: self.sessions(v) for v in VEHICLES}
        for v in VEHICLES:
            self.assertEqual(len(set(s.map for s in listed[v].values())), 2, "%s joined too early" % v)
        # auv_a ends its session: the joins wait no more, on auv_a (its own end) and on auv_b (the
        # session-ended notice), while auv_b still records.
        self.finish("auv_a")
        await_condition(self.lock, lambda: self.value("auv_b", "backend", "fleet_sessions_ended") == 1, 30,
                        "auv_a's session-ended notice on auv_b", state)
        for v in VEHICLES:
            listed = self.sessions(v)
            self.assertEqual(len(set(s.map for s in listed.values())), 1, "%s: not joined: %s" % (v, listed))
        self.finish("auv_b")
        await_condition(self.lock, lambda: self.value("auv_a", "backend", "fleet_sessions_ended") == 1 and
                        self.value("auv_a", "backend", "queue_length") == 0, 30,
                        "auv_b's session-ended notice on auv_a", state)

        with self.lock:
            st = self.status()
            kf = {v: list(self.keyframes[v]) for v in VEHICLES}
        a_b, b_b = st[("auv_a", "backend")], st[("auv_b", "backend")]
        a_d, b_d = st[("auv_a", "loop_detector")], st[("auv_b", "loop_detector")]
        for v, b in (("auv_a", a_b), ("auv_b", b_b)):
            self.assertEqual(b["fleet_refused"], 0, (v, b))
            self.assertEqual(b["fleet_feature_failures"], 0, (v, b))
        self.assertEqual(a_b["fleet_hashes_sent"], n_a)
        self.assertEqual(b_b["fleet_hashes_sent"], n_b)
        # Loops on both vehicles. Each pair is found by whichever of its two keyframes reaches a
        # vehicle second, and the other vehicle's hash comes later than its own keyframe there, so
        # some pairs are found by searching the other vehicle's hash (foreign_loops).
        self.assertGreater(a_d["global_loops"], 0, a_d)
        self.assertGreater(b_d["global_loops"], 0, b_d)
        self.assertGreater(a_d["foreign_loops"] + b_d["foreign_loops"], 0, (a_d, b_d))
        # Features crossed only for candidates, each keyframe's at most once (the cache), and some did.
        self.assertGreater(a_b["fleet_features_requested"], 0, a_b)
        self.assertGreater(b_b["fleet_features_requested"], 0, b_b)
        self.assertLessEqual(a_b["fleet_features_requested"], n_b, a_b)
        self.assertLessEqual(b_b["fleet_features_requested"], n_a, b_b)

        # The bandwidth per keyframe, as a thin link would carry it.
        hash_bytes = (a_b["fleet_hash_bytes_sent"] + b_b["fleet_hash_bytes_sent"]) / float(n_a + n_b)
        feature_bytes = a_b["fleet_feature_bytes_received"] + b_b["fleet_feature_bytes_received"]
        requested = a_b["fleet_features_requested"] + b_b["fleet_features_requested"]
        line = ("fleet bandwidth: %.0f bytes per keyframe with its hash only; %.0f bytes per keyframe whose features "
                "were asked for (%d of %d keyframes); %.0f bytes per keyframe in all"
                % (hash_bytes, feature_bytes / requested, requested, n_a + n_b,
                   hash_bytes + feature_bytes / float(n_a + n_b)))
        print(line)
        rospy.loginfo(line)
        self.assertLess(hash_bytes, 700)  # the hash as 8-bit codes (fleet/hash_codes, the default)

        # Both vehicles: two sessions, the other's marked with its vehicle, in one map.
        listed = {v: self.sessions(v) for v in VEHICLES}
        own = {v: kf[v][0].session for v in VEHICLES}
        other = {}
        for v, w in (("auv_a", "auv_b"), ("auv_b", "auv_a")):
            self.assertEqual(len(listed[v]), 2, listed[v])
            mine = listed[v][own[v]]
            theirs = [s for s in listed[v].values() if s.session != own[v]][0]
            other[v] = theirs.session
            self.assertEqual(mine.vehicle, "")
            self.assertEqual(theirs.vehicle, w)
            self.assertEqual(theirs.num_keyframes, len(kf[w]))
            self.assertEqual(mine.map, theirs.map, "%s: the two vehicles' sessions joined" % v)
        out = subprocess.run([SESSIONS_TOOL, "--ns", "/auv_a", "list"], capture_output=True, text=True, timeout=60)
        self.assertIn("auv_b_session_%d" % own["auv_b"], out.stdout, out.stdout + out.stderr)
        self.assertIn("from vehicle auv_b", out.stdout, out.stdout + out.stderr)
        # auv_b's session took id 1 on auv_b: auv_a's had taken 0 there first (active_session's next_session).
        self.assertEqual((own["auv_a"], other["auv_a"], own["auv_b"], other["auv_b"]), (0, 1, 1, 0))

        # Where: each map is drawn in auv_a's session frame (it ended first, so it leads both maps);
        # auv_b's keyframes against the ground truth, and the two vehicles against each other.
        with open(os.path.join(self.mission, "world_gt.csv")) as f:
            world = {(int(r["session"]), int(r["index"])): (float(r["x_m"]), float(r["y_m"]), float(r["yaw_rad"]))
                     for r in csv.DictReader(f)}
        origin = world[(0, kf["auv_a"][0].frame_index)]
        estimates = {}
        for v, session in (("auv_a", other["auv_a"]), ("auv_b", own["auv_b"])):
            p = self.path(v, session)
            self.assertEqual(len(p.poses), n_b)
            estimates[v] = [(q.pose.position.x, q.pose.position.y, yaw_of(q.pose.orientation)) for q in p.poses]
            errors = []
            for k, e in zip(kf["auv_b"], estimates[v]):
                truth = vehicle_from_camera(compose(invert(origin), world[(1, k.frame_index)]))
                errors.append(math.hypot(e[0] - truth[0], e[1] - truth[1]))
            rospy.loginfo("%s: auv_b's %d keyframes against the ground truth: mean %.4f m, max %.4f m", v, n_b,
                          sum(errors) / len(errors), max(errors))
            self.assertLessEqual(max(errors), MAX_ERROR_M, v)
        apart = max(math.hypot(a[0] - b[0], a[1] - b[1]) for a, b in zip(estimates["auv_a"], estimates["auv_b"]))
        rospy.loginfo("auv_a's and auv_b's joined maps at most %.4f m apart", apart)
        self.assertLessEqual(apart, MAX_DISAGREEMENT_M)


if __name__ == "__main__":
    rospy.init_node("check_fleet")
    rostest.rosrun("uw_multislam", "fleet", FleetTest)
