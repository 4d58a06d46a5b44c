#!/usr/bin/python3
"""rostest: bad input never crashes the pipeline or reaches the map, and every kind is counted on
/diagnostics.

Frames of a generated mission (make_survey, read back from its bag) are published one by one
with the test's own stamps and encodings, phase after phase:

  good frames; an empty image, an 8x8 image, a float image, a camera_info without focal length,
  an image whose size differs from camera_info, an image larger than ~max_image_pixels with a
  matching camera_info (each skipped and counted by kind); the next
  frames as rgba8, mono16 (12-bit values) and bayer_rggb8 (converted and processed); a NaN and a
  negative altitude (the last valid altitude is reused, counted) and a reading above
  max_altitude_m (refused, counted); a duplicated stamp and a late
  stamp (skipped, counted); a hovering camera whose camera_info is lost for 3 frames (skipped,
  counted, and the next frame continues the session); the mission again from its first stamp, as a bag that loops (a new
  session); a burst (frames dropped by the worker's short queue, counted; the gaps the drops
  leave in the stamps, longer than session_gap_s, must not start a session); images and camera_info
  without altitude for longer than input_timeout_s (a WARN naming the altitude topic; with
  ~fallback_altitude > 0 the frames are processed at that altitude instead, counted); then
  camera_info and altitude without images (a WARN naming the image topic).

The assertions then read the last odometry and loop-detector statuses on /diagnostics.
"""
import copy
import os
import shutil
import threading
import time
import unittest

import numpy as np
import rosgraph
import rospy
import rostest
from pipeline_fixture import NS, appender, bag_frames, connected, diagnostic_values, make_mission
import rosnode
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseWithCovarianceStamped
from sensor_msgs.msg import CameraInfo, Image, Range
from uw_multislam.msg import Keyframe

SURVEY = """
seed: 5
world: {width_m: 12, height_m: 10, metres_per_px: 0.008, featureless_fraction: 0.0}
sessions:
  - name: s0
    camera: {image_width: 240, image_height: 180, fx: 220, fy: 220, cx: 119.5, cy: 89.5}
    mission: {pattern: loop, start_m: [6.0, 5.0], length_m: 3.5, width_m: 2.5, laps: 1.0, speed_m_s: 0.35,
              frame_period_s: 1.0, altitude_m: 1.6, start_time_s: 0}
"""
RATE_HZ = 5.0
ALTITUDE_MAX_AGE_S = 1.0  # odometry_node/altitude_max_age_s (default)
MAX_IMAGE_PIXELS = 100000  # odometry_node/max_image_pixels in bad_input.test
SESSION_GAP_S = 2.5  # odometry_node/session_gap_s in bad_input.test: 3 frames of the burst




class BadInputTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.fallback = float(rospy.get_param("~fallback_altitude", 0.0))
        cls.tmp, out = make_mission("uwms_bad_input_")
        cls.frames = bag_frames(os.path.join(out, "s0.bag"))
        assert len(cls.frames) >= 20, len(cls.frames)

        cls.lock = threading.Lock()
        cls.images_published = 0
        cls.unsettled = []  # the last status of each phase that did not settle (settle())
        cls.poses, cls.keyframes, cls.odometry_statuses, cls.loop_statuses = [], [], [], []

        def on_diagnostics(msg):
            with cls.lock:
                for s in msg.status:
                    if s.name.endswith(": odometry"):
                        cls.odometry_statuses.append(s)
                    elif s.name.endswith(": loop_detector"):
                        cls.loop_statuses.append(s)

        cls.subs = [rospy.Subscriber(NS + "/odometry/pose", PoseWithCovarianceStamped, appender(cls.lock, cls.poses),
                                     queue_size=1000),
                    rospy.Subscriber(NS + "/keyframes", Keyframe, appender(cls.lock, cls.keyframes), queue_size=1000),
                    rospy.Subscriber("/diagnostics", DiagnosticArray, on_diagnostics, queue_size=100)]
        cls.pubs = [rospy.Publisher("/camera/image_raw", Image, queue_size=100),
                    rospy.Publisher("/camera/camera_info", CameraInfo, queue_size=100),
                    rospy.Publisher("/altitude", Range, queue_size=100)]
        cls.wait_for_pipeline()
        cls.run_phases()

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    @classmethod
    def wait_for_pipeline(cls, timeout=60.0):
        master = rosgraph.Master("/check_bad_input")
        wanted = ["/camera/image_raw", "/camera/camera_info", "/altitude"]
        deadline = time.time() + timeout
        while time.time() < deadline:
            _, subscribers, _ = master.getSystemState()
            subscribed = {topic: nodes for topic, nodes in subscribers}
            if all(subscribed.get(t) for t in wanted) and connected(cls.pubs):
                return
            time.sleep(0.5)
        raise AssertionError("the odometry did not subscribe to %s within %.0f s" % (wanted, timeout))

    @classmethod
    def publish(cls, image, info, altitude, stamp, period=1.0 / RATE_HZ):
        for m in (image, info, altitude):
            if m is not None:
                m.header.stamp = stamp
        cls.images_published += 1
        cls.pubs[0].publish(image)
        if info is not None:
            cls.pubs[1].publish(info)
        if altitude is not None:
            cls.pubs[2].publish(altitude)
        time.sleep(period)

    @classmethod
    def frame(cls, i):
        image, info, altitude = cls.frames[i % len(cls.frames)]
        # Copies of the headers too: publish() sets their stamps, the bag's frames must keep theirs.
        image, info, altitude = (copy.copy(m) for m in (image, info, altitude))
        for m in (image, info, altitude):
            m.header = copy.deepcopy(m.header)
        return Image(header=image.header, height=image.height, width=image.width, encoding=image.encoding,
                     is_bigendian=image.is_bigendian, step=image.step, data=image.data), \
            CameraInfo(header=info.header, width=info.width, height=info.height, distortion_model=info.distortion_model,
                       D=list(info.D), K=list(info.K), R=list(info.R), P=list(info.P)), \
            Range(header=altitude.header, radiation_type=altitude.radiation_type, field_of_view=altitude.field_of_view,
                  min_range=altitude.min_range, max_range=altitude.max_range, range=altitude.range)

    @staticmethod
    def pixels(image):
        channels = image.step // image.width
        return np.frombuffer(image.data, dtype=np.uint8).reshape(image.height, image.width, channels)

    @classmethod
    def reencoded(cls, image, encoding):
        bgr = cls.pixels(image)
        if bgr.shape[2] == 1:
            bgr = np.repeat(bgr, 3, axis=2)
        out = Image(header=image.header, height=image.height, width=image.width, encoding=encoding)
        if encoding == "rgba8":
            px = np.dstack([bgr[:, :, ::-1], np.full(bgr.shape[:2], 255, np.uint8)])
            out.step, out.data = image.width * 4, px.tobytes()
        elif encoding == "mono16":  # a 12-bit sensor
            grey = bgr.mean(axis=2).astype(np.uint16) * 16
            out.step, out.data = image.width * 2, grey.astype("<u2").tobytes()
        elif encoding == "bayer_rggb8":
            mosaic = np.empty(bgr.shape[:2], np.uint8)
            mosaic[0::2, 0::2] = bgr[0::2, 0::2, 2]
            mosaic[0::2, 1::2] = bgr[0::2, 1::2, 1]
            mosaic[1::2, 0::2] = bgr[1::2, 0::2, 1]
            mosaic[1::2, 1::2] = bgr[1::2, 1::2, 0]
            out.step, out.data = image.width, mosaic.tobytes()
        return out

    @classmethod
    def stamp_of(cls, i):
        return cls.frames[i % len(cls.frames)][0].header.stamp

    @classmethod
    def run_phases(cls):
        d = rospy.Duration
        # 1. Good frames.
        for i in range(8):
            cls.publish(*cls.frame(i), cls.stamp_of(i))
        last = cls.stamp_of(7)
        cls.poses_after_good = cls.settle()
        # 2. Bad images and camera_infos, stamps after the last good one.
        image, info, altitude = cls.frame(8)
        bad = [
            (Image(encoding="mono8", width=0, height=0, step=0, data=b""), info),                    # empty
            (Image(encoding="mono8", width=8, height=8, step=8, data=bytes(range(64))),            # tiny
             CameraInfo(width=8, height=8, K=[8, 0, 4, 0, 8, 4, 0, 0, 1])),
            (Image(encoding="32FC1", width=240, height=180, step=960, data=bytes(960 * 180)), info),  # float
            (Image(encoding="yuv422", width=240, height=180, step=480, data=bytes(480 * 180)), info),  # YUV
            (image, CameraInfo(width=240, height=180, K=[0] * 9)),                                 # zero focal length
            (image, CameraInfo(width=320, height=240, K=[220, 0, 159.5, 0, 220, 119.5, 0, 0, 1])),  # size mismatch
            (Image(encoding="mono8", width=400, height=300, step=400, data=bytes(range(200)) * 600),  # too large
             CameraInfo(width=400, height=300, K=[220, 0, 199.5, 0, 220, 149.5, 0, 0, 1])),
        ]
        assert 400 * 300 > MAX_IMAGE_PIXELS
        for k, (im, ci) in enumerate(bad):
            cls.publish(im, ci, cls.frame(8)[2], last + d(0.1 * (k + 1)))
        cls.poses_after_bad = cls.settle()
        # 3. Converted encodings, the next frames of the mission.
        for i, encoding in zip((8, 9, 10), ("rgba8", "mono16", "bayer_rggb8")):
            image, info, altitude = cls.frame(i)
            cls.publish(cls.reencoded(image, encoding), info, altitude, cls.stamp_of(i))
        # 4. NaN and negative altitude (the last valid one is reused). Before frame 11's reading, one
        # alone at its stamp above slam/odometry/max_altitude_m (an altimeter's "no bottom"): refused
        # and counted, and frame 11's NaN replaces it.
        image, info, altitude = cls.frame(11)
        altitude.range, altitude.max_range = 500.0, 0.0
        altitude.header.stamp = cls.stamp_of(11)
        cls.pubs[2].publish(altitude)
        for i, bad_range in ((11, float("nan")), (12, -1.0)):
            image, info, altitude = cls.frame(i)
            altitude.range = bad_range
            cls.publish(image, info, altitude, cls.stamp_of(i))
        # 5. The same frame twice, then a late one, then a good one.
        cls.publish(*cls.frame(12), cls.stamp_of(12))
        cls.publish(*cls.frame(11), cls.stamp_of(12) - d(0.5))
        cls.publish(*cls.frame(13), cls.stamp_of(13))
        cls.publish(*cls.frame(14), cls.stamp_of(14))
        cls.poses_before_loop = cls.settle()
        cls.status_before_loop = cls.next_odometry_status()
        # 5b. The camera hovers (the same image) and its camera_info is lost for 3 frames, stamps 1 s
        # apart: the images are skipped (nothing pairs with them), the next one is processed, and
        # the 4 s since the last processed frame are no gap in the recording (no session).
        image, info, altitude = cls.frame(14)
        with cls.lock:
            cls.poses_before_unpaired = len(cls.poses)
        for k in range(1, 4):
            cls.publish(image, None, altitude, cls.stamp_of(14) + d(1.0 * k))
        cls.publish(image, info, altitude, cls.stamp_of(14) + d(4.0))
        cls.poses_after_unpaired = cls.await_count(cls.poses, cls.poses_before_unpaired + 1, 5.0)
        cls.next_odometry_status()  # the second status from now on was computed after the frame's processing
        cls.status_after_unpaired = cls.next_odometry_status()
        # 6. The bag loops: its first frames again, with their first stamps.
        for i in range(6):
            cls.publish(*cls.frame(i), cls.stamp_of(i))
        base = cls.stamp_of(5)
        # 7. A burst: 40 frames as fast as they can be sent, their stamps 1 s apart (as recorded):
        # every 3 frames the queue drops in a row leave a gap longer than session_gap_s.
        for k in range(40):
            cls.publish(*cls.frame(6 + k), base + d(1.0 * (k + 1)), period=0.002)
        cls.settle()
        last_altitude = base + d(1.0 * 40)
        # 8. The altitude topic falls silent: images and camera_info only. The first ones are within
        # altitude_max_age_s of the last reading and use it; the others have no altitude.
        with cls.lock:
            cls.poses_before_silence = len(cls.poses)
            cls.statuses_before_silence = len(cls.odometry_statuses)
        n_silent = int((2.0 + 2.5) * RATE_HZ)
        offsets = [0.1 + 0.2 * (k + 1) for k in range(n_silent)]  # clear of the bound: 0.3, 0.5, ...
        cls.n_silent_with_altitude = sum(o < ALTITUDE_MAX_AGE_S for o in offsets)
        for k in range(n_silent):
            image, info, _ = cls.frame(k)
            cls.publish(image, info, None, last_altitude + d(offsets[k]))
        cls.settle()
        with cls.lock:
            cls.poses_in_silence = len(cls.poses) - cls.poses_before_silence
            cls.silence_statuses = cls.odometry_statuses[cls.statuses_before_silence:]
            cls.final_odometry = cls.odometry_statuses[-1] if cls.odometry_statuses else None
            cls.final_loops = cls.loop_statuses[-1] if cls.loop_statuses else None
            cls.all_odometry = list(cls.odometry_statuses)
            before_image_silence = len(cls.odometry_statuses)
        # 9. The image topic falls silent (a dead camera, a wrong topic): camera_info and altitude
        # keep coming for 4 s, twice input_timeout_s.
        stamp = last_altitude + d(offsets[-1])
        for k in range(int(4.0 * RATE_HZ)):
            _, info, altitude = cls.frame(k)
            stamp = stamp + d(1.0 / RATE_HZ)
            info.header.stamp = altitude.header.stamp = stamp
            cls.pubs[1].publish(info)
            cls.pubs[2].publish(altitude)
            time.sleep(1.0 / RATE_HZ)
        with cls.lock:
            cls.image_silence_statuses = cls.odometry_statuses[before_image_silence:]

    @classmethod
    def next_odometry_status(cls, timeout=10.0):
        """The values of the first odometry status published from now on (every 0.5 s), or None."""
        with cls.lock:
            seen = len(cls.odometry_statuses)
        deadline = time.time() + timeout
        while time.time() < deadline:
            with cls.lock:
                if len(cls.odometry_statuses) > seen:
                    return diagnostic_values(cls.odometry_statuses[seen])
            time.sleep(0.05)
        return None

    @classmethod
    def await_count(cls, store, count, timeout):
        """len(store) once it reaches `count`, or after `timeout` seconds (then below it)."""
        deadline = time.time() + timeout
        while True:
            with cls.lock:
                if len(store) >= count or time.time() > deadline:
                    return len(store)
            time.sleep(0.05)

    @staticmethod
    def idle(v):
        """An odometry status of an idle pipeline: no image waiting for its pairing, none queued,
        every frame the worker took finished (published or skipped)."""
        return v["images_waiting_pairing"] == 0 and v["queue_length"] == 0 and v["frames_finished"] == v["frames_processed"]

    @classmethod
    def settle(cls, timeout=60.0):
        """Until the odometry is idle in two consecutive statuses published after this call (0.5 s
        apart) that received no image between them; then len(poses). A pipeline that never settles
        within `timeout` seconds is counted in cls.unsettled (test_each_phase_settled) and the count
        returned as it is."""
        with cls.lock:
            seen = len(cls.odometry_statuses)
        deadline = time.time() + timeout
        while time.time() < deadline:
            with cls.lock:
                new = [diagnostic_values(st) for st in cls.odometry_statuses[seen:]]
            if len(new) >= 2 and cls.idle(new[-2]) and cls.idle(new[-1]) and \
                    new[-2]["images_received"] == new[-1]["images_received"]:
                with cls.lock:
                    return len(cls.poses)
            time.sleep(0.05)
        cls.unsettled.append(new[-1] if new else None)
        with cls.lock:
            return len(cls.poses)

    def odometry(self):
        self.assertIsNotNone(self.final_odometry, "no odometry status on /diagnostics")
        return diagnostic_values(self.final_odometry)

    def where_frames_went(self, v):
        """The counts that tell where the frames went, for a failure's message."""
        keys = ("images_received", "images_not_paired", "skipped_no_camera_info", "skipped_no_altitude",
                "dropped_queue_full", "frames_processed", "fixed_altitude_frames", "time_jumps_forward")
        return "images published %d; %s" % (self.images_published, ", ".join("%s %g" % (k, v[k]) for k in keys))

    def test_each_phase_settled(self):
        """Every phase ended with the odometry idle (its counts are final, not a snapshot in flight)."""
        self.assertEqual(self.unsettled, [], "phases that did not settle (their last odometry status)")

    def test_good_frames_are_processed(self):
        self.assertGreaterEqual(self.poses_after_good, 6)

    def test_each_bad_image_and_camera_info_is_skipped_and_counted_by_kind(self):
        v = self.odometry()
        self.assertEqual(self.poses_after_bad, self.poses_after_good, "a bad frame produced a pose")
        self.assertEqual(v["skipped_empty_image"], 1)
        self.assertEqual(v["skipped_tiny_image"], 1)
        self.assertEqual(v["skipped_encoding"], 2)  # 32FC1, yuv422
        self.assertEqual(v["skipped_camera_info"], 1)
        self.assertEqual(v["skipped_size_mismatch"], 1)
        self.assertEqual(v["skipped_image_layout"], 0)
        self.assertEqual(v["skipped_image_too_large"], 1)

    def test_convertible_encodings_and_bad_altitudes_are_processed(self):
        v = self.odometry()
        self.assertEqual(v["bad_altitude_replaced"], 2)
        self.assertEqual(v["altitudes_refused"], 3)  # 500 m, NaN, -1
        self.assertEqual(v["altitudes_above_max_altitude"], 1)
        self.assertEqual(v["skipped_by_odometry"], 0, "a frame reached the odometry and was refused there")
        # Each of them gives a pose: 3 converted + 2 with a bad altitude + 2 good after the
        # duplicate and the late frame, all processed (the status after them: nothing queued).
        before = self.status_before_loop
        self.assertIsNotNone(before, "no odometry status after the converted frames")
        self.assertEqual(before["queue_length"], 0)
        self.assertEqual(self.poses_before_loop - self.poses_after_bad, 3 + 2 + 2)
        # And each pose is a measured motion: a frame the conversion spoilt would still give a
        # pose, the previous motion reused (a fallback). None on this textured seabed, so far.
        self.assertEqual(before["fallbacks"], 0, "a converted frame was not matched")

    def test_images_without_camera_info_are_skipped_without_splitting_the_session(self):
        v = self.status_after_unpaired
        self.assertIsNotNone(v, "no odometry status after the images without camera_info")
        self.assertEqual(v["skipped_no_camera_info"], 3, self.where_frames_went(v))
        self.assertEqual(self.poses_after_unpaired - self.poses_before_unpaired, 1, "the frame after them")
        # The skipped images were received: the 4 s since the last processed frame are no gap.
        self.assertEqual(v["time_jumps_forward"], 0, self.where_frames_went(v))
        self.assertEqual(v["sessions"], self.status_before_loop["sessions"])

    def test_duplicated_and_late_stamps_are_skipped(self):
        v = self.odometry()
        self.assertEqual(v["skipped_duplicate_stamp"], 1)
        self.assertEqual(v["skipped_out_of_order"], 1)

    def test_a_looping_bag_starts_a_new_session(self):
        v = self.odometry()
        self.assertEqual(v["time_jumps_back"], 1)
        self.assertEqual(v["time_jumps_forward"], 0, self.where_frames_went(v))
        self.assertGreaterEqual(v["sessions"], 2)
        with self.lock:
            sessions = {k.session for k in self.keyframes}
        self.assertGreaterEqual(len(sessions), 2)
        for s in sessions:  # keyframe ids count up from 0 in each session: nothing interleaved
            ids = [k.keyframe for k in self.keyframes if k.session == s]
            self.assertEqual(ids, list(range(len(ids))), "session %d" % s)

    def test_a_burst_drops_frames_and_counts_every_one(self):
        v = self.odometry()
        self.assertGreater(v["dropped_queue_full"], 0)
        # Our own drops are no gap in the recording: no session from them.
        self.assertEqual(v["time_jumps_forward"], 0, self.where_frames_went(v))
        # Every synchronised frame is processed, dropped or still queued.
        self.assertEqual(v["frames_synchronised"], v["frames_processed"] + v["dropped_queue_full"] + v["queue_length"])
        self.assertEqual(v["images_received"], v["frames_synchronised"] + v["images_not_paired"])
        self.assertGreater(v["ms_per_frame_mean"], 0.0)
        self.assertGreaterEqual(v["ms_per_frame_max"], v["ms_per_frame_mean"])
        self.assertGreater(v["keyframes"], 3)
        with self.lock:
            self.assertEqual(v["keyframes"], len(self.keyframes))

    def test_drops_and_skips_raise_a_warning(self):
        levels = [s.level for s in self.all_odometry]
        self.assertIn(DiagnosticStatus.OK, levels, "the good frames at the start should report OK")
        warned = [s.message for s in self.all_odometry if s.level == DiagnosticStatus.WARN]
        self.assertTrue(any("skipped_empty_image" in m for m in warned), warned[:5])
        self.assertTrue(any("dropped_queue_full" in m for m in warned), warned[:5])

    def test_a_silent_altitude_topic(self):
        v = self.odometry()
        warned = [s.message for s in self.silence_statuses if s.level == DiagnosticStatus.WARN]
        if self.fallback > 0:
            self.assertGreater(v["fixed_altitude_frames"], 0)
            self.assertGreater(self.poses_in_silence, 0, "the fixed altitude should keep the odometry going")
            self.assertTrue(any("fixed_altitude_frames" in m for m in warned), warned[-3:])
        else:
            self.assertEqual(v["fixed_altitude_frames"], 0)
            # Altitude by stamp: the images within altitude_max_age_s of the last reading use it.
            self.assertEqual(self.poses_in_silence, self.n_silent_with_altitude, "frames without altitude were processed")
            self.assertGreater(v["skipped_no_altitude"], 0)
            self.assertTrue(any("no altitude on /altitude" in m for m in warned), warned[-3:])

    def test_a_silent_image_topic_is_named(self):
        warned = [s.message for s in self.image_silence_statuses if s.level == DiagnosticStatus.WARN]
        self.assertTrue(any("no image on /camera/image_raw" in m and "while camera_info arrives and altitude arrives"
                            in m for m in warned), warned[-3:])

    def test_loop_detector_diagnostics(self):
        self.assertIsNotNone(self.final_loops, "no loop_detector status on /diagnostics")
        v = diagnostic_values(self.final_loops)
        with self.lock:
            n = len(self.keyframes)
        self.assertEqual(v["keyframes_received"], n)
        self.assertEqual(v["dropped_queue_full"], 0)
        self.assertEqual(v["skipped_bad_keyframe"], 0)
        self.assertGreaterEqual(v["sessions"], 2)
        self.assertEqual(v["hashes"], n)
        self.assertEqual(v["mode"], "both")

    def test_nodes_still_run(self):
        state = rosgraph.Master("/check_bad_input").getSystemState()
        nodes = dict(state[0]).get(NS + "/odometry/pose", [])
        self.assertTrue(nodes, "nobody publishes the odometry pose any more")
        for node in nodes:
            self.assertTrue(rosnode.rosnode_ping(node, max_count=1), "%s does not answer" % node)


if __name__ == "__main__":
    rospy.init_node("check_bad_input")
    rostest.rosrun("uw_multislam", "check_bad_input", BadInputTest)
