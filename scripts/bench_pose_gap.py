#!/usr/bin/python3
"""The current pose and a service during a large optimisation: the back-end must never
make the per-frame pose or a service call wait for an optimisation. Starts backend_node (no
store) on the running master, feeds it one session of N featureless keyframes in a straight
line, then, while odometry/pose arrives at RATE Hz and list_sessions is called back to back, the
loops that make it optimise the whole N-keyframe map. Prints one line:

  pose gap: N keyframes, optimisation X ms, longest gap in pose Y ms (odometry/pose every P ms), gap / optimisation Y/X,
  longest list_sessions call S ms (C calls), call / optimisation S/X

Not a test: numbers for this machine. usage: bench_pose_gap.py [--keyframes N] [--rate HZ]
"""
import argparse
import subprocess
import threading
import time

import roslib.packages
import rospy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Pose2D, PoseStamped, PoseWithCovarianceStamped
from uw_multislam.msg import Keyframe, Loop
from uw_multislam.srv import ListSessions

NS = "/pose_gap_bench"


def keyframe(k):
    m = Keyframe()
    m.header.stamp = rospy.Time(1000 + k)
    m.session, m.keyframe, m.frame_index, m.altitude_m = 0, k, k, 2.0
    m.width, m.height, m.fx, m.fy, m.cx, m.cy = 320, 240, 300.0, 300.0, 159.5, 119.5
    m.descriptor_size = 128
    m.odometry_pose = Pose2D(0.5 * k, 0.0, 0.0)
    if k > 0:
        m.motion = Pose2D(0.5, 0.0, 0.0)
        m.motion_covariance = [1e-4, 0, 0, 0, 1e-4, 0, 0, 0, 1e-4]
        m.status = Keyframe.MATCHED
    m.scale = 1.0
    return m


def loop(a, b):
    m = Loop()
    m.kind = Loop.LOCAL
    m.session_a, m.keyframe_a, m.frame_a = 0, a, a
    m.session_b, m.keyframe_b, m.frame_b = 0, b, b
    m.pose = Pose2D(0.5 * (b - a) + 2.0, 1.0, 0.3)  # far from the odometry: many iterations
    m.covariance = [1e-4, 0, 0, 0, 1e-4, 0, 0, 0, 1e-4]
    m.inliers = 100
    return m


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--keyframes", type=int, default=5000)
    parser.add_argument("--rate", type=float, default=100.0)
    args = parser.parse_args()
    rospy.init_node("bench_pose_gap", anonymous=True)
    state = {"optimisations": 0, "optimise_ms_max": 0.0, "keyframes": 0, "arrivals": [], "calls": []}
    lock = threading.Lock()

    def on_diag(msg):
        for s in msg.status:
            v = {kv.key: kv.value for kv in s.values}
            if "optimisations" in v and "keyframes_received" in v:
                with lock:
                    state["optimisations"] = int(float(v["optimisations"]))
                    state["optimise_ms_max"] = float(v["optimise_ms_max"])
                    state["keyframes"] = int(float(v["keyframes_received"]))

    def on_pose(_):
        with lock:
            state["arrivals"].append(time.monotonic())

    node = subprocess.Popen([roslib.packages.find_node("uw_multislam", "backend_node")[0], "__ns:=" + NS,
                             "__name:=backend_node", "_store_path:=", "_diagnostic_period:=0.2", "_queue_size:=100000",
                             "_publish_tf:=false"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        rospy.Subscriber("/diagnostics", DiagnosticArray, on_diag, queue_size=100)
        rospy.Subscriber(NS + "/pose", PoseStamped, on_pose, queue_size=1000)
        kf_pub = rospy.Publisher(NS + "/keyframes", Keyframe, queue_size=100000)
        loop_pub = rospy.Publisher(NS + "/loops", Loop, queue_size=100)
        odo_pub = rospy.Publisher(NS + "/odometry/pose", PoseWithCovarianceStamped, queue_size=100)
        deadline = time.time() + 60
        while time.time() < deadline and (kf_pub.get_num_connections() == 0 or odo_pub.get_num_connections() == 0):
            time.sleep(0.1)
        time.sleep(1.0)
        n = args.keyframes
        for k in range(n):
            kf_pub.publish(keyframe(k))
        deadline = time.time() + 300
        while time.time() < deadline and state["keyframes"] < n:
            time.sleep(0.1)
        stop = threading.Event()

        def odometry():
            period = 1.0 / args.rate
            nxt = time.monotonic()
            while not stop.is_set():
                p = PoseWithCovarianceStamped()
                p.header.stamp = rospy.Time.now()
                p.header.frame_id = "session_0"
                p.pose.pose.position.x = 0.5 * (n - 1)
                p.pose.pose.orientation.w = 1.0
                odo_pub.publish(p)
                nxt += period
                time.sleep(max(0.0, nxt - time.monotonic()))

        def caller():
            rospy.wait_for_service(NS + "/list_sessions", timeout=30)
            call = rospy.ServiceProxy(NS + "/list_sessions", ListSessions, persistent=True)
            while not stop.is_set():
                t0 = time.monotonic()
                call()
                with lock:
                    state["calls"].append(time.monotonic() - t0)
                time.sleep(0.005)

        threads = [threading.Thread(target=odometry), threading.Thread(target=caller)]
        for thread in threads:
            thread.start()
        time.sleep(2.0)
        with lock:
            before = state["optimisations"]
            state["arrivals"] = []
            state["calls"] = []
        for a, b in ((0, n - 1), (1, n - 2), (2, n - 3)):  # optimise_every = 3: one optimisation of the map
            loop_pub.publish(loop(a, b))
        deadline = time.time() + 120
        while time.time() < deadline and state["optimisations"] <= before:
            time.sleep(0.05)
        time.sleep(2.0)
        stop.set()
        for thread in threads:
            thread.join()
        with lock:
            t = state["arrivals"]
            gaps = [b - a for a, b in zip(t, t[1:])]
            calls = list(state["calls"])
            optimised = state["optimisations"] > before
            ms = state["optimise_ms_max"]
        longest = 1e3 * max(gaps) if gaps else float("nan")
        longest_call = 1e3 * max(calls) if calls else float("nan")
        period_ms = 1e3 / args.rate
        ratio = (lambda x: x / ms if optimised and ms > 0 else float("nan"))
        # The reference, measured in the same run: a pose or a call that waited for the
        # optimisation (a back-end that took its state lock for it) would take the
        # whole optimisation.
        print("pose gap: %d keyframes, optimisation %s ms, longest gap in pose %.1f ms (odometry/pose every %.1f ms), "
              "gap / optimisation %.2f, longest list_sessions call %.1f ms (%d calls), call / optimisation %.2f"
              % (n, "%.0f" % ms if optimised else "NOT RUN", longest, period_ms, ratio(longest), longest_call,
                 len(calls), ratio(longest_call)))
    finally:
        node.terminate()
        node.wait(timeout=60)


if __name__ == "__main__":
    main()
