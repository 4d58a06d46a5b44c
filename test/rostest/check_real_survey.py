#!/usr/bin/python3
"""rostest: live equals offline on a real stills survey, with the default configuration.

../shared/data/skerki_survey/s0 (148 real ROV frames, 13-22 s apart) is written as a bag by
folder_to_bag and played at its real stamps on simulated time, 50 times faster (rosbag play --clock
-r 50; paused while more than 30 frames wait for the odometry, so that a loaded machine fills no queue),
through slam.launch with the default configuration. The odometry must keep one session (the
gap rule follows the camera's 13 s rhythm: a fixed 10 s session_gap_s cut a session at every frame)
and publish the keyframes and odometry poses offline_slam computes on the same folder, to 1e-6 (the
equivalence test's tolerance). With max_interval_s 10 s every frame is a keyframe, so the default
~drop_policy newest takes every frame in order and the two heads process the same frames. The
altimeter travels as a float32 Range: offline_slam reads a copy of the folder whose altitudes are
those float32 values, so that both heads see the same numbers.

The data lives beside the clone, not in it: without ../shared/data/skerki_survey/s0 the test is
skipped, saying so.
"""
import csv
import os
import shutil
import struct
import subprocess
import tempfile
import threading
import time
import unittest

import rospy
import rostest
from pipeline_fixture import NS, SENSOR_TOPICS, DiagnosticsWatch, tool, wait_for_subscribers, wait_until_quiet
from std_srvs.srv import SetBool
from uw_multislam.msg import Keyframe
from uw_multislam.srv import ListSessions

HERE = os.path.dirname(os.path.realpath(__file__))
SURVEY = os.path.join(os.path.dirname(os.path.dirname(HERE)), "..", "shared", "data", "skerki_survey", "s0")
TOLERANCE = 1e-6  # metres and radians: the same computation on the same pixels
START_TIME = 1500000000  # the bag's time of stamp_s 0
PLAY_RATE = 50.0  # 13 s apart: 0.26 s of wall time, above a frame's cost on these 576 x 384 images
PLAYER = "/real_survey_player"
WAITING_MAX, WAITING_MIN = 30, 5  # frames waiting for the odometry: pause the player above, resume below


def float32(value):
    return struct.unpack("f", struct.pack("f", value))[0]


def read_csv(path):
    with open(path) as f:
        return list(csv.DictReader(f))


@unittest.skipUnless(os.path.isdir(SURVEY), "the real survey %s is not there (it lives beside the clone, in "
                     "../shared/data): nothing to compare" % os.path.normpath(SURVEY))
class RealSurveyTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="uwms_real_survey_")
        # The folder as the bag carries it: its altitudes rounded to float32.
        folder = os.path.join(cls.tmp, "s0")
        shutil.copytree(SURVEY, folder, ignore=shutil.ignore_patterns("gt.csv"))
        rows = read_csv(os.path.join(folder, "frames.csv"))
        with open(os.path.join(folder, "frames.csv"), "w") as f:
            f.write("index,image,stamp_s,altitude_m\n")
            for r in rows:
                f.write("%s,%s,%s,%.9g\n" % (r["index"], r["image"], r["stamp_s"], float32(float(r["altitude_m"]))))
        cls.frames = {START_TIME * 10**9 + round(float(r["stamp_s"]) * 1e9): int(r["index"]) for r in rows}
        bag = os.path.join(cls.tmp, "s0.bag")
        subprocess.run([tool("folder_to_bag"), folder, bag, "--start-time", str(START_TIME), "--no-ground-truth"],
                       check=True, timeout=120, stdout=subprocess.DEVNULL)
        # The reference, while the bag plays.
        run = os.path.join(cls.tmp, "run")
        offline = subprocess.Popen([tool("offline_slam"), "--session", folder, "--out", run, "--quiet"])
        cls.lock = threading.Lock()
        cls.keyframes = []
        cls.last_message = time.time()

        def on_keyframe(msg):
            with cls.lock:
                cls.keyframes.append(msg)
                cls.last_message = time.time()

        cls.diagnostics = DiagnosticsWatch(("odometry",), cls.lock)
        cls.subs = [rospy.Subscriber(NS + "/keyframes", Keyframe, on_keyframe, queue_size=1000), cls.diagnostics]
        wait_for_subscribers(SENSOR_TOPICS + [NS + "/keyframes"], "/check_real_survey")
        started = time.time()
        cls.pauses = cls.play(bag)
        wait_until_quiet(cls.lock, lambda: cls.last_message, 5.0)
        cls.live_s = time.time() - started
        offline.wait(timeout=300)
        cls.expected = [(int(r["session"]), int(r["index"]), float(r["x_m"]), float(r["y_m"]), float(r["yaw_rad"]))
                        for r in read_csv(os.path.join(run, "odometry.csv"))]

    @classmethod
    def play(cls, bag):
        """Plays the bag; while more than WAITING_MAX frames wait for the odometry (its diagnostics, every
        second), the player is paused (its pause_playback service) until they are down to WAITING_MIN:
        a loaded machine must not fill the worker's queue (100 frames with the default queue_size), whose
        drops would leave frames unprocessed. Returns how many times it paused."""
        player = subprocess.Popen(["rosbag", "play", "-q", "--clock", "--wait-for-subscribers", "-d", "1", "-r",
                                   str(PLAY_RATE), bag, "--topics"] + SENSOR_TOPICS + ["__name:=" + PLAYER[1:]])
        pause = rospy.ServiceProxy(PLAYER + "/pause_playback", SetBool)
        paused, pauses, deadline = False, 0, time.time() + 300
        while player.poll() is None and time.time() < deadline:
            with cls.lock:
                odometry = cls.diagnostics.get("odometry")
                waiting = odometry.get("queue_length", 0) + odometry.get("images_waiting_pairing", 0)
            wanted = waiting > (WAITING_MIN if paused else WAITING_MAX)
            if wanted != paused:
                try:
                    pause(wanted)
                    paused = wanted
                    pauses += wanted
                except (rospy.ServiceException, rospy.ROSException):
                    pass  # the player is starting or has finished: asked again at the next poll
            time.sleep(0.2)
        if player.poll() is None:
            player.kill()
        player.wait()
        return pauses

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def test_one_session_with_the_keyframes_and_poses_of_offline_slam(self):
        with self.lock:
            got = list(self.keyframes)
            odometry = dict(self.diagnostics.get("odometry"))
        rospy.loginfo("real survey: %d keyframes live in %.1f s (the player paused %d times); odometry %s", len(got),
                      self.live_s, self.pauses,
                      {k: odometry.get(k) for k in ("images_received", "frames_finished", "sessions",
                                                    "time_jumps_forward", "skipped_for_newest", "tracking_losses")})
        self.assertEqual({k.session for k in got}, {0}, "one session, as offline: the camera's 13 s are no gap")
        self.assertEqual({e[0] for e in self.expected}, {0})
        self.assertEqual(len(got), len(self.expected))
        self.assertGreater(len(got), 140, "every frame a keyframe (max_interval_s 10 s against 13 s)")
        for k, e in zip(got, self.expected):
            index = self.frames[k.header.stamp.to_nsec()]
            self.assertEqual(index, e[1], "keyframe %d: the frame" % k.keyframe)
            self.assertEqual(k.frame_index, e[1])
            for g, x, what in ((k.odometry_pose.x, e[2], "x"), (k.odometry_pose.y, e[3], "y"),
                               (k.odometry_pose.theta, e[4], "yaw")):
                self.assertAlmostEqual(g, x, delta=TOLERANCE, msg="%s of keyframe %d" % (what, k.keyframe))
        listed = rospy.ServiceProxy(NS + "/list_sessions", ListSessions)()
        self.assertEqual(listed.status.code, 0)
        self.assertEqual([(s.session, s.num_keyframes) for s in listed.sessions], [(0, len(self.expected))])


if __name__ == "__main__":
    rospy.init_node("check_real_survey")
    rostest.rosrun("uw_multislam", "real_survey", RealSurveyTest)
