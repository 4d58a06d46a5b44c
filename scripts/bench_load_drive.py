#!/usr/bin/python3
"""Drives one bench_load.sh run: publishes a bag's frames (image, camera_info, altitude) at a given
rate, each stamped with the time it is sent (a live camera), and measures the latency from an
image's stamp to its odometry/pose (wall time at receipt minus the stamp). Waits until the
odometry is idle, then prints one JSON line: the latencies' median and p99 (ms and input periods),
frames sent, the machine's load average at the start and the CPU this driver took while sending
(a fraction of one core: it shares the machine with the pipeline), and the odometry's counters
from /diagnostics (processed, prepared_ahead, skipped_for_newest, dropped_queue_full, sessions,
tracking_losses, keyframes, ms_per_frame_mean), and the p99 of the poses of keyframes and of the
other frames apart (a keyframe is where the skip rule may take an older frame than the newest).
Also the time-averaged age of the newest pose received (from the first pose to the last: at each
moment, the time since the stamp of the freshest pose so far), which a worker that waits for a
fresher frame must lower, not only the latency of the poses it publishes.

    bench_load_drive.py BAG RATE_HZ [--ns /uw_multislam] [--timeout 120]
"""
import argparse
import json
import os
import struct
import sys
import threading
import time

import rosbag
import rospy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseWithCovarianceStamped
from sensor_msgs.msg import CameraInfo, Image, Range

TOPICS = ["/camera/image_raw", "/camera/camera_info", "/altitude"]


def frames_of(bag):
    """(image, camera_info, altitude) per image, matched by stamp."""
    by_topic = {t: {} for t in TOPICS}
    with rosbag.Bag(bag) as b:
        for topic, msg, _ in b.read_messages(topics=TOPICS):
            by_topic[topic][msg.header.stamp] = msg
    stamps = sorted(by_topic[TOPICS[0]])
    return [(by_topic[TOPICS[0]][s], by_topic[TOPICS[1]].get(s), by_topic[TOPICS[2]].get(s)) for s in stamps]


def percentile(values, q):
    v = sorted(values)
    if not v:
        return float("nan")
    k = min(len(v) - 1, max(0, int(round(q / 100.0 * (len(v) - 1)))))
    return v[k]


def mean_pose_age(received):
    """Time average of (now - stamp of the freshest pose received so far) between the first and the
    last receipt; `received`: (receipt time, stamp) pairs, s."""
    r = sorted(received)
    if len(r) < 2:
        return float("nan")
    area, freshest = 0.0, r[0][1]
    for (t0, s0), (t1, _) in zip(r, r[1:]):
        freshest = max(freshest, s0)
        d = t1 - t0
        area += d * (t0 - freshest) + d * d / 2.0
    return area / (r[-1][0] - r[0][0])


def main():
    p = argparse.ArgumentParser()
    p.add_argument("bag")
    p.add_argument("rate", type=float)
    p.add_argument("--ns", default="/uw_multislam")
    p.add_argument("--timeout", type=float, default=120.0)
    a = p.parse_args(rospy.myargv()[1:])
    frames = [f for f in frames_of(a.bag) if f[1] is not None and f[2] is not None]
    rospy.init_node("bench_load_drive", disable_signals=True)
    lock = threading.Lock()
    latencies, status, keyframe_stamps = [], {}, set()

    def on_pose(msg):
        now = time.time()
        with lock:
            latencies.append((msg.header.stamp.to_nsec(), now - msg.header.stamp.to_sec(), now))

    def on_keyframe(raw):  # only the header's stamp (seq, secs, nsecs first): no message class needed
        secs, nsecs = struct.unpack_from("<II", raw._buff, 4)
        with lock:
            keyframe_stamps.add(secs * 1000000000 + nsecs)

    def on_diag(msg):
        for s in msg.status:
            if s.name.endswith(": odometry"):
                with lock:
                    status.clear()
                    status.update({kv.key: float(kv.value) for kv in s.values})

    rospy.Subscriber(a.ns + "/odometry/pose", PoseWithCovarianceStamped, on_pose, queue_size=10000)
    rospy.Subscriber("/diagnostics", DiagnosticArray, on_diag, queue_size=100)
    rospy.Subscriber(a.ns + "/keyframes", rospy.AnyMsg, on_keyframe, queue_size=1000)
    pubs = [rospy.Publisher(t, m, queue_size=1000) for t, m in zip(TOPICS, (Image, CameraInfo, Range))]
    deadline = time.time() + 60
    while any(pub.get_num_connections() == 0 for pub in pubs):
        if time.time() > deadline:
            print(json.dumps({"error": "the odometry did not subscribe within 60 s"}))
            return 1
        time.sleep(0.05)
    time.sleep(1.0)  # the subscribers' connections settle (get_num_connections counts them early)
    period = 1.0 / a.rate
    load_average = os.getloadavg()[0]
    cpu_start = sum(os.times()[:2])
    start = time.time()
    for i, (image, info, altitude) in enumerate(frames):
        delay = start + i * period - time.time()
        if delay > 0:
            time.sleep(delay)  # the camera's rate
        stamp = rospy.Time.from_sec(time.time())  # wall time: no simulated clock here
        altitude.header.stamp = info.header.stamp = image.header.stamp = stamp
        pubs[2].publish(altitude)
        pubs[1].publish(info)
        pubs[0].publish(image)
    sent_s = time.time() - start
    driver_cpu = (sum(os.times()[:2]) - cpu_start) / sent_s

    def idle():
        with lock:
            s = dict(status)
        return s.get("images_received") == len(frames) and s.get("queue_length") == 0 and \
            s.get("images_waiting_pairing") == 0 and s.get("frames_finished") == s.get("frames_processed")

    deadline = time.time() + a.timeout
    while not idle() and time.time() < deadline:
        time.sleep(0.1)
    time.sleep(1.5)  # one more status after the last frame
    with lock:
        lat, s, kf = list(latencies), dict(status), set(keyframe_stamps)
    ms = [1e3 * x for _, x, _ in lat]
    ms_kf = [1e3 * x for t, x, _ in lat if t in kf]
    ms_other = [1e3 * x for t, x, _ in lat if t not in kf]
    age_ms = 1e3 * mean_pose_age([(r, r - x) for _, x, r in lat])
    out = {"rate_hz": a.rate, "frames": len(frames), "sent_s": sent_s, "idle": idle(), "poses": len(lat),
           "load_average": load_average, "driver_cpu": driver_cpu,
           "latency_median_ms": percentile(ms, 50), "latency_p99_ms": percentile(ms, 99),
           "latency_max_ms": max(ms) if ms else float("nan"),
           "latency_median_periods": percentile(ms, 50) / (1e3 * period),
           "pose_age_mean_ms": age_ms, "pose_age_mean_periods": age_ms / (1e3 * period),
           "latency_p99_periods": percentile(ms, 99) / (1e3 * period),
           "keyframe_poses": len(ms_kf), "latency_p99_keyframes_ms": percentile(ms_kf, 99),
           "latency_p99_others_ms": percentile(ms_other, 99), "latency_median_keyframes_ms": percentile(ms_kf, 50)}
    for k in ("images_received", "frames_processed", "prepared_ahead", "skipped_for_newest", "dropped_queue_full", "sessions",
              "tracking_losses", "keyframes", "ms_per_frame_mean", "ms_per_frame_recent", "input_period_ms",
              "images_not_paired", "fallbacks", "waits_for_fresher", "early_keyframes"):
        out[k] = s.get(k, float("nan"))
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
