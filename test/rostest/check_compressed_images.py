#!/usr/bin/python3
"""rostest: compressed images. slam.launch with transport:=compressed plays a bag
of JPEG sensor_msgs/CompressedImage (folder_to_bag --image-format jpeg, on
/camera/image_raw/compressed). Debian has no compressed_image_transport plugin, so the odometry
decodes them itself (OpenCV); with the plugin installed the plugin does it. Either way:

- every image of the bag is received and processed, none skipped or dropped;
- the odometry's keyframe trajectory is as accurate as the raw images' (offline_slam on the same
  dataset folder: the raw path, equal to the pipeline on raw images to 1e-6, slam_pipeline.test);
- two corrupt CompressedImages (a truncated JPEG, bytes that are no JPEG), sent after the bag with
  their camera_info and altitude, are each skipped and counted (skipped_corrupt_image), and the
  node keeps running.
"""
import csv
import math
import os
import shutil
import subprocess
import threading
import time
import unittest

import rosbag
import rosgraph
import rospy
import rostest
from pipeline_fixture import NS, DiagnosticsWatch, appender, connected, make_mission, tool, wait_for_subscribers
from sensor_msgs.msg import CameraInfo, CompressedImage, Range
from uw_multislam.msg import Keyframe

# One short loop, 240 x 180 images 0.5 s apart (about 50 frames).
SURVEY = """
seed: 5
world: {width_m: 12, height_m: 10, metres_per_px: 0.008, featureless_fraction: 0.0}
sessions:
  - name: s0
    camera: {image_width: 240, image_height: 180, fx: 220, fy: 220, cx: 119.5, cy: 89.5}
    mission: {pattern: loop, start_m: [6.0, 5.0], length_m: 2.5, width_m: 2.0, laps: 1.0, speed_m_s: 0.35,
              frame_period_s: 0.5, altitude_m: 1.6, start_time_s: 0}
"""
JPEG_QUALITY = 80  # compressed_image_transport's default
PLAY_RATE = 8.0  # 16 frames per second of bag time 0.5 s: 4 images per second
IMAGE_TOPIC = "/camera/image_raw/compressed"
SENSOR_TOPICS = [IMAGE_TOPIC, "/camera/camera_info", "/altitude"]
# Keyframe positions, JPEG vs raw. Measured (2026-11-23, OpenCV 4.6, libjpeg-turbo): the same 14
# keyframes, positions at most 2.0 mm apart, ATE 8.4 mm (JPEG) vs 8.7 mm (raw) on the 9 m loop. The
# run is deterministic (the same bytes, the same computation), so the bounds only leave room for
# another libjpeg version: 1.5 x the measured difference, and 1 mm of ATE. JPEG moves pixels by
# about 1.3 grey levels on average (gtest CompressedImages.Jpeg...); a decoder that flipped,
# cropped or mis-scaled the images would move the keyframes by centimetres or lose tracking.
MAX_POSITION_DIFFERENCE_M = 0.003
MAX_ATE_INCREASE_M = 0.001


def read_csv(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def ate(positions, truth):
    """RMSE of keyframe positions against the ground truth (both in the session's frame)."""
    errors = [(x - truth[i][0]) ** 2 + (y - truth[i][1]) ** 2 for i, (x, y) in positions.items()]
    return math.sqrt(sum(errors) / len(errors))


class CompressedImagesTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp, mission = make_mission("uwms_compressed_", SURVEY)
        folder = os.path.join(mission, "s0")
        cls.bag = os.path.join(cls.tmp, "s0_jpeg.bag")
        subprocess.run([tool("folder_to_bag"), folder, cls.bag, "--image-format", "jpeg", "--jpeg-quality",
                        str(JPEG_QUALITY), "--no-ground-truth"], check=True, timeout=120)
        with rosbag.Bag(cls.bag) as bag:
            info = bag.get_type_and_topic_info().topics
            cls.bag_topics = {t: (i.msg_type, i.message_count) for t, i in info.items()}
            cls.last = {t: m for t, m, _ in bag.read_messages(topics=SENSOR_TOPICS)}  # the last of each
        cls.n_images = cls.bag_topics[IMAGE_TOPIC][1]

        # The raw path's keyframes, and the ground truth, from the dataset folder.
        run = os.path.join(cls.tmp, "raw_run")
        subprocess.run([tool("offline_slam"), "--session", folder, "--out", run, "--quiet"], check=True, timeout=300)
        cls.raw = {int(r["index"]): (float(r["x_m"]), float(r["y_m"])) for r in read_csv(os.path.join(run, "odometry.csv"))}
        cls.truth = {int(r["index"]): (float(r["x_m"]), float(r["y_m"])) for r in read_csv(os.path.join(folder, "gt.csv"))}

        cls.lock = threading.Lock()
        cls.keyframes = []
        cls.diagnostics = DiagnosticsWatch(("odometry",), cls.lock)
        cls.subs = [rospy.Subscriber(NS + "/keyframes", Keyframe, appender(cls.lock, cls.keyframes), queue_size=1000),
                    cls.diagnostics]
        wait_for_subscribers(SENSOR_TOPICS, "/check_compressed_images")
        cls.subscriptions = {t: n for t, n in rosgraph.Master("/check_compressed_images").getSystemState()[1]}

        subprocess.run(["rosbag", "play", "-q", "--wait-for-subscribers", "-d", "1", "-r", str(PLAY_RATE), cls.bag,
                        "--topics"] + SENSOR_TOPICS,
                       check=True, timeout=120)
        cls.await_odometry(cls.n_images, "every image of the bag processed")
        with cls.lock:
            cls.after_bag = cls.diagnostics.get("odometry")
            cls.bag_keyframes = list(cls.keyframes)

        cls.send_corrupt_images()
        cls.await_odometry(cls.n_images + 2, "the two corrupt images skipped")
        with cls.lock:
            cls.final = cls.diagnostics.get("odometry")

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    @classmethod
    def await_odometry(cls, n, what, timeout=120.0):
        """Until the odometry has received n images and finished every one of them."""
        def done(v):
            return (v.get("images_received") == n and v.get("images_waiting_pairing") == 0 and
                    v.get("queue_length") == 0 and v.get("frames_processed") == v.get("frames_synchronised"))
        last = cls.diagnostics.await_values("odometry", done, timeout)
        if not (last and done(last)):
            raise AssertionError("timed out after %.0f s waiting for %s; last odometry status %s" % (timeout, what, last))

    @classmethod
    def send_corrupt_images(cls):
        """A truncated JPEG and bytes that are no JPEG, each with its camera_info and altitude,
        0.5 s and 1 s after the bag's last frame."""
        pubs = {t: rospy.Publisher(t, m, queue_size=10) for t, m in
                zip(SENSOR_TOPICS, (CompressedImage, CameraInfo, Range))}
        deadline = time.time() + 30
        while not connected(pubs.values()):
            if time.time() > deadline:
                raise AssertionError("no connection to the odometry's subscriptions")
            time.sleep(0.1)
        good = cls.last[IMAGE_TOPIC]
        truncated = CompressedImage(format=good.format, data=good.data[:len(good.data) // 2])
        garbage = CompressedImage(format=good.format, data=bytes(range(256)) * 20)
        for k, image in enumerate((truncated, garbage)):
            stamp = good.header.stamp + rospy.Duration(0.5 * (k + 1))
            image.header.stamp = stamp
            image.header.frame_id = good.header.frame_id
            info, altitude = cls.last["/camera/camera_info"], cls.last["/altitude"]
            info.header.stamp = altitude.header.stamp = stamp
            for topic, msg in ((IMAGE_TOPIC, image), ("/camera/camera_info", info), ("/altitude", altitude)):
                pubs[topic].publish(msg)

    def keyframe_positions(self, keyframes):
        return {k.frame_index: (k.odometry_pose.x, k.odometry_pose.y) for k in keyframes}

    def test_the_bag_holds_compressed_images_only(self):
        self.assertEqual(self.bag_topics[IMAGE_TOPIC][0], "sensor_msgs/CompressedImage")
        self.assertNotIn("/camera/image_raw", self.bag_topics)
        self.assertGreaterEqual(self.n_images, 40)
        self.assertEqual(self.last[IMAGE_TOPIC].format, "bgr8; jpeg compressed bgr8")

    def test_the_odometry_subscribes_to_the_compressed_topic(self):
        odometry = NS + "/odometry_node"
        manager = NS + "/manager"
        self.assertTrue({odometry, manager} & set(self.subscriptions.get(IMAGE_TOPIC, [])), self.subscriptions)
        self.assertFalse({odometry, manager} & set(self.subscriptions.get("/camera/image_raw", [])),
                         "the raw topic is subscribed too")

    def test_every_image_is_processed(self):
        v = self.after_bag
        self.assertEqual(v["images_received"], self.n_images)
        self.assertEqual(v["frames_synchronised"], self.n_images)
        self.assertEqual(v["frames_processed"], self.n_images)
        for key in ("images_not_paired", "skipped_no_camera_info", "skipped_no_altitude", "dropped_queue_full",
                    "skipped_empty_image", "skipped_encoding", "skipped_corrupt_image", "skipped_image_layout",
                    "skipped_tiny_image", "skipped_size_mismatch", "skipped_by_odometry", "skipped_duplicate_stamp",
                    "skipped_out_of_order", "tracking_losses"):
            self.assertEqual(v[key], 0, key)
        self.assertEqual({k.session for k in self.bag_keyframes}, {0})

    def test_accuracy_is_close_to_the_raw_images(self):
        got = self.keyframe_positions(self.bag_keyframes)
        self.assertGreaterEqual(len(got), 10)
        ate_jpeg, ate_raw = ate(got, self.truth), ate(self.raw, self.truth)
        common = sorted(set(got) & set(self.raw))
        diffs = [math.hypot(got[i][0] - self.raw[i][0], got[i][1] - self.raw[i][1]) for i in common]
        rospy.loginfo("compressed images: %d keyframes (raw %d, %d in common), ATE %.4f m (raw %.4f m), keyframe "
                      "positions differ by at most %.4f m", len(got), len(self.raw), len(common), ate_jpeg, ate_raw,
                      max(diffs))
        self.assertGreaterEqual(len(common), 0.8 * len(self.raw), "mostly the same keyframes")
        self.assertLessEqual(max(diffs), MAX_POSITION_DIFFERENCE_M)
        self.assertLessEqual(ate_jpeg, ate_raw + MAX_ATE_INCREASE_M)

    def test_corrupt_images_are_counted_skips(self):
        v = self.final
        self.assertEqual(v["images_received"], self.n_images + 2)
        self.assertEqual(v["frames_processed"], self.n_images + 2)
        self.assertEqual(v["skipped_corrupt_image"], 2)
        for key in ("skipped_encoding", "skipped_empty_image", "skipped_by_odometry", "skipped_no_camera_info"):
            self.assertEqual(v[key], 0, key)
        with self.lock:
            self.assertEqual(len(self.keyframes), len(self.bag_keyframes), "a corrupt image made a keyframe")


if __name__ == "__main__":
    rospy.init_node("check_compressed_images")
    rostest.rosrun("uw_multislam", "check_compressed_images", CompressedImagesTest)
