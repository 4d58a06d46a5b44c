#!/usr/bin/python3
"""rostest: replay.launch from its start to its end.

replay.launch starts with delay:=0 (rosbag play publishes at once) on the fixture mission's s0.bag,
the nodelets loading meanwhile, with a session store. The player starts paused and is resumed once
the odometry is connected (scripts/resume_player.py): the odometry receives every image of the bag
(its diagnostics' images_received) and session 0's keyframe 0 is the bag's first image. Then the
replay ends by itself (scripts/replay_end.py), saying so, once the pipeline has processed the bag:
every keyframe the odometry published is in the store, and the store was closed (no write-ahead
log left). ~wait_for_odometry false is for measuring what the wait prevents (the images lost
without it); it is not registered as a test.
"""
import os
import shutil
import sqlite3
import subprocess
import threading
import time
import unittest

import rospy
import rostest
from geometry_msgs.msg import PoseWithCovarianceStamped
from pipeline_fixture import (NS, SENSOR_TOPICS, appender, await_condition, bag_frames, DiagnosticsWatch, make_mission,
                              stop_launch)
from uw_multislam.msg import Keyframe


class ReplayStartTest(unittest.TestCase):
    def setUp(self):
        self.tmp, self.mission = make_mission("uwms_replay_start_")
        self.wait = rospy.get_param("~wait_for_odometry", True)

    def tearDown(self):
        stop_launch(self.launch)
        shutil.rmtree(self.tmp, ignore_errors=True)

    def test_the_odometry_receives_every_image_from_the_first(self):
        bag = os.path.join(self.mission, "s0.bag")
        images = [image.header.stamp for (image,) in bag_frames(bag, SENSOR_TOPICS[:1])]
        lock = threading.Lock()
        keyframes, poses = [], []
        subs = [rospy.Subscriber(NS + "/keyframes", Keyframe, appender(lock, keyframes), queue_size=1000),
                rospy.Subscriber(NS + "/odometry/pose", PoseWithCovarianceStamped, appender(lock, poses),
                                 queue_size=1000),
                DiagnosticsWatch(("odometry",), lock)]

        def odometry():  # its newest status
            return subs[-1].get("odometry")

        store = os.path.join(self.tmp, "sessions.db")
        log = open(os.path.join(self.tmp, "launch.log"), "w")
        self.launch = subprocess.Popen(["roslaunch", "uw_multislam", "replay.launch", "bag:=" + bag, "delay:=0",
                                        "rate:=4", "camera_mount:=0 0 0 0", "store_path:=" + store,
                                        "wait_for_odometry:=" + ("true" if self.wait else "false")],
                                       stdout=log, stderr=subprocess.STDOUT)
        # The bag is over when the odometry's pose of its last image is out (every processed frame has
        # one); the diagnostics (every second) then count what the odometry received.
        await_condition(lock, lambda: any(p.header.stamp == images[-1] for p in poses), 120,
                        "the odometry's pose of the bag's last image", lambda: ": %s" % odometry())
        # Every image received is finished or was passed over for a newer one (~drop_policy newest, on a
        # loaded machine): the odometry is done with the bag.
        await_condition(lock, lambda: odometry().get("frames_finished", -1) + odometry().get("skipped_for_newest", 0) +
                        odometry().get("dropped_queue_full", 0) == odometry().get("images_received") and
                        odometry().get("frames_finished", 0) >= len(poses), 10,
                        "the odometry's diagnostics after the last image", lambda: ": %s" % odometry())
        for s in subs:
            s.unregister()
        with lock:
            received = int(odometry()["images_received"])
            first = [k for k in keyframes if k.session == 0 and k.keyframe == 0]
        rospy.loginfo("replay_start (wait_for_odometry %s): the odometry received %d of the bag's %d images; "
                      "session 0 starts at image %s", self.wait, received, len(images),
                      images.index(first[0].header.stamp) if first else "none")
        self.assertEqual(received, len(images))
        self.assertTrue(first, "no keyframe 0 of session 0")
        self.assertEqual(first[0].header.stamp, images[0])

        # The end: replay.launch stops by itself once the pipeline is done with the bag.
        played = time.time()
        try:
            self.launch.wait(timeout=120)
        except subprocess.TimeoutExpired:
            self.fail("replay.launch still running 120 s after the bag's last image")
        ended_s = time.time() - played
        log.close()
        with open(log.name) as f:
            said = f.read()
        self.assertIn("replay_end: the bag(s) ended", said)
        self.assertIn("the pipeline is idle", said)
        self.assertIn("Ending the replay", said)
        with lock:
            published = sorted((k.session, k.keyframe) for k in keyframes)
        self.assertFalse(os.path.exists(store + "-wal"), "the store's write-ahead log is left: not closed")
        with sqlite3.connect(store) as db:
            stored = sorted(db.execute("SELECT session, keyframe FROM keyframes").fetchall())
        rospy.loginfo("replay_start: replay.launch ended %.1f s after the bag's last image; %d keyframes published, "
                      "%d in the store", ended_s, len(published), len(stored))
        self.assertTrue(published)
        self.assertEqual(stored, published)


if __name__ == "__main__":
    rospy.init_node("check_replay_start")
    rostest.rosrun("uw_multislam", "check_replay_start", ReplayStartTest)
