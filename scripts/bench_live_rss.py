#!/usr/bin/python3
"""Memory of the live session through ROS (the bar: the live session's RSS grows
<= 10 kB per keyframe beyond the cache budget). Generates one long lawnmower session (the demo's
second session, a loop, flown LAPS times over its seabed, so local loops keep reading old keyframes back),
then plays its bag through replay.launch standalone (one process per node) with a session store,
once per value of slam/loops/page_live_after (default 50 and 0 = live keyframes kept). Every
--period seconds it reads each node's VmRSS and the keyframes the back-end has received; the
slope of VmRSS over keyframes (least squares over the samples past --skip keyframes) is the
growth per keyframe. For the loop detector it is given twice: as measured, and with its feature
cache's bytes (diagnostics feature_cache_mb, bounded by slam/loops/feature_cache_mb) subtracted.
Prints one line per case:

  bench_live_rss keyframes=N page_live_after=P odometry_kB_per_kf=X loop_detector_kB_per_kf=Y
      loop_detector_beyond_cache_kB_per_kf=Y2 backend_kB_per_kf=Z total_beyond_cache_kB_per_kf=T
      final_rss_MB=odometry/loop_detector/backend

Not a test: numbers for this machine. Needs a built workspace (devel/setup.bash sourced); starts
its own master on a free port.
usage: scripts/bench_live_rss.py [--laps 20] [--rate 6] [--page-live-after 50,0]
"""
import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time

import rospkg
import yaml

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_paging import init_node, pid_of, rss_kb, start_master, stop  # noqa: E402
from atomic_file import write_atomically  # noqa: E402  (the tools' safe writer, on bench_paging's path)

NODES = ("odometry_node", "loop_detector_node", "backend_node")


def slope(xs, ys):
    n = float(len(xs))
    mx, my = sum(xs) / n, sum(ys) / n
    sxx = sum((x - mx) ** 2 for x in xs)
    return sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sxx if sxx > 0 else float("nan")


def make_mission(out, laps, bin_dir):
    spec = yaml.safe_load(subprocess.check_output([os.path.join(bin_dir, "make_survey"), "--dump-config",
                                                   "--preset", "demo"]))
    spec["sessions"] = spec["sessions"][1:2]  # the demo's second session: laps of a loop
    spec["sessions"][0]["mission"]["laps"] = laps
    spec["sessions"][0]["mission"]["start_time_s"] = 0
    cfg = os.path.join(out, "long.yaml")
    write_atomically(cfg, yaml.safe_dump(spec))
    subprocess.check_call([os.path.join(bin_dir, "make_survey"), "--out", os.path.join(out, "survey"), "--config", cfg,
                           "--quiet"])
    return os.path.join(out, "survey", spec["sessions"][0]["name"] + ".bag")


def run_case(bag, config, store, rate, period, env):
    """Samples (keyframes, {node: VmRSS kB}, cache MB) until the bag has played and the queues emptied."""
    import rospy
    from diagnostic_msgs.msg import DiagnosticArray
    launch = subprocess.Popen(["roslaunch", "uw_multislam", "replay.launch", "standalone:=true", "camera_mount:=0 0 0 0", "bag:=" + bag,
                               "rate:=%g" % rate, "store_path:=" + store, "slam_config:=" + config],
                              stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT, env=env)
    diag = {}
    lock = threading.Lock()

    def on_diag(msg):
        with lock:
            for s in msg.status:
                for node in NODES:
                    if ("/" + node + ":") in s.name:
                        diag.setdefault(node, {}).update({v.key: v.value for v in s.values})

    samples = []
    try:
        init_node("bench_live_rss")
        sub = rospy.Subscriber("/diagnostics", DiagnosticArray, on_diag, queue_size=100)
        pids, idle = {}, 0
        while launch.poll() is None:
            time.sleep(period)
            for node in NODES:
                if node not in pids:
                    pids[node] = pid_of("/uw_multislam/" + node)
            if any(p is None for p in pids.values()) or len(pids) < len(NODES):
                pids = {k: v for k, v in pids.items() if v is not None}
                continue
            with lock:
                b = dict(diag.get("backend_node", {}))
                l = dict(diag.get("loop_detector_node", {}))
            kf = int(float(b.get("keyframes_received", 0)))
            rss = {n: rss_kb(p) for n, p in pids.items()}
            samples.append((kf, rss, float(l.get("feature_cache_mb", 0.0))))
            # The bag has played once the keyframes stop coming and every queue is empty.
            idle = idle + 1 if len(samples) > 1 and samples[-2][0] == kf and kf > 0 and \
                float(b.get("queue_length", 1)) == 0 and float(l.get("queue_length", 1)) == 0 else 0
            if idle >= max(3, int(10 / period)):
                break
        sub.unregister()
        return samples, l
    finally:
        stop(launch)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--laps", type=float, default=20.0, help="laps of the demo's loop (1.15 in the demo; at most 20)")
    p.add_argument("--rate", type=float, default=6.0, help="rosbag play rate (the bag has one frame a second)")
    p.add_argument("--period", type=float, default=2.0, help="seconds between samples")
    p.add_argument("--skip", type=int, default=150, help="keyframes before the fit (caches and pools warming up)")
    p.add_argument("--page-live-after", default="50,0", help="values of slam/loops/page_live_after, comma-separated")
    a = p.parse_args()
    tmp = tempfile.mkdtemp(prefix="uwms_bench_live_rss_")
    # make_survey from the sourced workspace (its devel or install space), else UWMS_BIN_DIR.
    bin_dir = os.environ.get("UWMS_BIN_DIR", "")
    for d in os.environ.get("CMAKE_PREFIX_PATH", "").split(":"):
        if d and os.path.exists(os.path.join(d, "lib", "uw_multislam", "make_survey")):
            bin_dir = os.path.join(d, "lib", "uw_multislam")
            break
    if not os.path.exists(os.path.join(bin_dir, "make_survey")):
        sys.exit("bench_live_rss: no make_survey (source the workspace's setup.bash, or set UWMS_BIN_DIR)")
    master, env = start_master()
    try:
        bag = make_mission(tmp, a.laps, bin_dir)
        with open(os.path.join(rospkg.RosPack().get_path("uw_multislam"), "config", "slam.yaml")) as f:
            text = f.read()
        if "  page_live_after: 50 " not in text:
            sys.exit("bench_live_rss: page_live_after 50 not in config/slam.yaml")
        for value in [int(v) for v in a.page_live_after.split(",")]:
            config = os.path.join(tmp, "slam_%d.yaml" % value)
            write_atomically(config, text.replace("  page_live_after: 50 ", "  page_live_after: %d " % value))
            store = os.path.join(tmp, "store_%d.db" % value)
            samples, loops = run_case(bag, config, store, a.rate, a.period, env)
            fit = [s for s in samples if s[0] >= a.skip]
            if len(fit) < 3:
                sys.exit("bench_live_rss: %d samples past %d keyframes (of %d): a longer mission (--laps) or a "
                         "shorter --period" % (len(fit), a.skip, samples[-1][0] if samples else 0))
            kfs = [s[0] for s in fit]
            per = {n: slope(kfs, [s[1][n] for s in fit]) for n in NODES}
            beyond = slope(kfs, [s[1]["loop_detector_node"] - s[2] * 1024.0 for s in fit])
            last = samples[-1]
            print("bench_live_rss keyframes=%d page_live_after=%d odometry_kB_per_kf=%.2f loop_detector_kB_per_kf=%.2f "
                  "loop_detector_beyond_cache_kB_per_kf=%.2f backend_kB_per_kf=%.2f total_beyond_cache_kB_per_kf=%.2f "
                  "final_rss_MB=%.0f/%.0f/%.0f cache_MB=%.1f keyframes_paged_live=%d" % (
                      last[0], value, per["odometry_node"], per["loop_detector_node"], beyond, per["backend_node"],
                      per["odometry_node"] + beyond + per["backend_node"],
                      last[1]["odometry_node"] / 1024.0, last[1]["loop_detector_node"] / 1024.0,
                      last[1]["backend_node"] / 1024.0, last[2],
                      int(float(loops.get("keyframes_paged_live", 0)))), flush=True)
    finally:
        stop(master, 30)
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
