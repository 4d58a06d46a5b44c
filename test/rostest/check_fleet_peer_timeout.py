#!/usr/bin/env python3
"""A peer that never answers (rostest fleet_peer_timeout.test), and one whose hashes were made from
another kind of features (refused, counted in fleet_refused). Our back-end forwards a request
for another vehicle's keyframe features to that vehicle's keyframe_features and waits for it at
most ~fleet/peer_timeout_s (1 s here); after a timeout the vehicle is not asked again for as long
(UNAVAILABLE at once); then the next request goes through. Counted on /diagnostics
(fleet_feature_timeouts, fleet_feature_failures)."""
import threading
import time
import unittest

import rospy
import rostest
from pipeline_fixture import DiagnosticsWatch, await_condition, connected
from uw_multislam.msg import KeyframeHash, Status
from uw_multislam.srv import KeyframeFeatures, KeyframeFeaturesResponse, ListSessions

TIMEOUT_S = 1.0  # ~fleet/peer_timeout_s in the launch file


def foreign_hash(vehicle="auv_c", features="sift"):
    """`vehicle`'s first keyframe of its session 4, as its back-end would send it (our hash settings
    but `features`)."""
    m = KeyframeHash()
    m.header.stamp = rospy.Time(1000.0)
    m.session, m.keyframe, m.frame_index = 4, 0, 0
    m.hash_mode = KeyframeHash.SORTED_DCT
    m.projection_seed = int(rospy.get_param("/auv_a/slam/loops/global/projection_seed", 20231122))
    m.num_features = int(rospy.get_param("/auv_a/slam/odometry/features/num_features", 500))
    m.features = features
    m.values = [0.01 * (i % 7) for i in range(384)]
    m.vehicle = vehicle
    m.altitude_m = 2.0
    m.width, m.height, m.fx, m.fy, m.cx, m.cy = 240, 180, 220.0, 220.0, 119.5, 89.5
    return m


class FleetPeerTimeoutTest(unittest.TestCase):
    def setUp(self):
        self.lock = threading.Lock()
        self.release = threading.Event()
        self.served = []  # requests auv_c's service got

        def serve(req):  # auv_c: holds each request until the test releases it
            with self.lock:
                self.served.append(req)
            self.release.wait(120)
            r = KeyframeFeaturesResponse()
            r.status.code = Status.OK
            r.keyframe.session, r.keyframe.keyframe = req.session, req.keyframe
            r.keyframe.descriptor_size = 128
            return r

        self.diagnostics = DiagnosticsWatch(("backend",), self.lock, namespace="auv_a")
        self.srv = rospy.Service("/auv_c/keyframe_features", KeyframeFeatures, serve)

    def tearDown(self):
        if hasattr(self, "proxy"):
            self.proxy.close()
        self.release.set()
        self.srv.shutdown()
        self.diagnostics.unregister()

    def call(self, session):
        # One persistent connection: after the first call the times are the back-end's answers
        # alone (no master lookup, no TCP set-up inside the "refused at once" bound).
        if not hasattr(self, "proxy"):
            self.proxy = rospy.ServiceProxy("/auv_a/keyframe_features", KeyframeFeatures, persistent=True)
        start = time.time()
        r = self.proxy(session=session, keyframe=0)
        return r, time.time() - start

    def test_a_hung_peer_is_left_at_the_deadline_and_not_asked_again_for_as_long(self):
        pub = rospy.Publisher("/auv_a/fleet/hashes_in", KeyframeHash, queue_size=10)
        await_condition(self.lock, lambda: connected([pub]), 60, "the back-end's fleet/hashes_in")
        rospy.wait_for_service("/auv_a/list_sessions", timeout=60)
        rospy.wait_for_service("/auv_a/keyframe_features", timeout=60)
        # A vehicle whose hashes were made from ORB features: not comparable with ours (SIFT), refused.
        pub.publish(foreign_hash("auv_d", "orb"))
        await_condition(self.lock, lambda: self.diagnostics.get().get("fleet_refused") == 1, 30, "auv_d's hash refused",
                        lambda: " (diagnostics: %s)" % self.diagnostics.get())
        pub.publish(foreign_hash())
        sessions = lambda: rospy.ServiceProxy("/auv_a/list_sessions", ListSessions)().sessions
        deadline = time.time() + 30
        while not [s for s in sessions() if s.vehicle == "auv_c"] and time.time() < deadline:
            time.sleep(0.1)
        ours = [s for s in sessions() if s.vehicle == "auv_c"]
        self.assertEqual(len(ours), 1, "auv_c's session was not taken")
        self.assertEqual([s for s in sessions() if s.vehicle == "auv_d"], [])
        local = ours[0].session

        # 1: auv_c holds the request: answered UNAVAILABLE at the deadline, not when auv_c answers.
        r, took = self.call(local)
        self.assertEqual(r.status.code, Status.UNAVAILABLE, r.status.message)
        self.assertIn("within 1.0 s", r.status.message)
        self.assertGreaterEqual(took, TIMEOUT_S)
        self.assertLess(took, TIMEOUT_S + 4.0)
        with self.lock:
            self.assertEqual([(q.session, q.keyframe) for q in self.served], [(4, 0)])  # in auv_c's ids
        # 2: right after it auv_c is not asked again: refused at once, for as long as the timeout.
        r, took = self.call(local)
        self.assertEqual(r.status.code, Status.UNAVAILABLE, r.status.message)
        self.assertIn("not asked again", r.status.message)
        self.assertLess(took, TIMEOUT_S)
        with self.lock:
            self.assertEqual(len(self.served), 1)
        await_condition(self.lock, lambda: self.diagnostics.get().get("fleet_feature_timeouts") == 1 and
                        self.diagnostics.get().get("fleet_feature_failures") == 2, 30, "one timeout, two failures",
                        lambda: " (diagnostics: %s)" % self.diagnostics.get())
        # 3: auv_c answers again; once the quiet time is over the next request goes through (in
        # our ids).
        self.release.set()
        deadline = time.time() + 30
        while time.time() < deadline:
            r, took = self.call(local)
            if r.status.code == Status.OK or "not asked again" not in r.status.message:
                break
            time.sleep(0.1)  # still within the quiet time
        self.assertEqual(r.status.code, Status.OK, r.status.message)
        self.assertEqual((r.keyframe.session, r.keyframe.keyframe), (local, 0))
        with self.lock:
            self.assertEqual(len(self.served), 2)


if __name__ == "__main__":
    rospy.init_node("check_fleet_peer_timeout")
    rostest.rosrun("uw_multislam", "check_fleet_peer_timeout", FleetPeerTimeoutTest)
