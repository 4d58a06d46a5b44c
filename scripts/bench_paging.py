#!/usr/bin/python3
"""The loop detector's memory per stored keyframe through ROS (paging of stored keyframes): slam.launch
standalone (one process per node) on a store of N synthetic keyframes (bench_scale --keep), with
reload_stored:=true and mode:=localisation, once with slam/loops/page_stored true (the default:
hashes in RAM, features read from the back-end's store on demand) and once false (every feature
sent and kept). For each it waits until the loop detector's diagnostics count the N keyframes
reloaded, reads the loop_detector_node process's VmRSS, and subtracts the same process's VmRSS
in a run on an empty store (reload of nothing). Prints one line per case:

  bench_paging keyframes=N page_stored=true cache=warm loop_detector_rss_MB=X ram_per_stored_keyframe_kB=Y reload_s=Z
      keyframes_paged=P backend_ready_s=R handover_s=H

reload_s: from the launch until the loop detector holds every stored keyframe; backend_ready_s:
until the back-end's first diagnostics (its store restored, keyframes taken; they come every
second, so up to 1 s late); handover_s: the
back-end's handover of the stored keyframes to the loop detector (its diagnostics handover_s).

Not a test: numbers for this machine. Needs a built workspace (devel/setup.bash sourced) and
rostest's roslaunch; starts its own master on a free port.
usage: scripts/bench_paging.py STORE.db --keyframes N [--page-stored true|false|both] [--cold]
"""
import argparse
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time

import rospkg

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "src", "tools"))
from atomic_file import write_atomically  # noqa: E402  (the tools' safe writer)


def free_port():
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def rss_kb(pid):
    with open("/proc/%d/status" % pid) as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    raise RuntimeError("no VmRSS for %d" % pid)


def pid_of(node):
    """The process id of a ROS node of this master (asked of the node itself, through its API)."""
    import rosnode
    import xmlrpc.client
    uri = rosnode.get_api_uri(rospy_master(), node, skip_cache=True)
    if not uri:
        return None
    code, _, pid = xmlrpc.client.ServerProxy(uri).getPid("/bench_paging")
    return pid if code == 1 else None


def rospy_master():
    import rosgraph
    return rosgraph.Master("/bench_paging")


def start_master():
    """A ROS master of its own on a free port (ROS_MASTER_URI set here too); returns it and the env."""
    port = free_port()
    env = dict(os.environ, ROS_MASTER_URI="http://localhost:%d" % port)
    os.environ["ROS_MASTER_URI"] = env["ROS_MASTER_URI"]
    return subprocess.Popen(["rosmaster", "--core", "-p", str(port)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.STDOUT, env=env), env


def init_node(name):
    """Waits (up to 20 s) for the master, then makes this process a ROS node (once)."""
    import rospy
    for _ in range(100):
        try:
            rospy.get_master().getPid()
            break
        except Exception:
            time.sleep(0.2)
    if not rospy.core.is_initialized():
        rospy.init_node(name, anonymous=True, disable_signals=True)


def stop(process, timeout=60):
    """SIGINT (roslaunch and rosmaster shut down cleanly on it), then SIGKILL after `timeout` s."""
    process.send_signal(signal.SIGINT)
    try:
        process.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()


def run_case(store, config, expect, env):
    """slam.launch on `store` (None: an empty one) with the given slam config; the loop detector's
    VmRSS (kB) once it reports `expect` keyframes reloaded, and the seconds that took."""
    import rospy
    from diagnostic_msgs.msg import DiagnosticArray
    launch = subprocess.Popen(["roslaunch", "uw_multislam", "slam.launch", "standalone:=true", "camera_mount:=0 0 0 0",
                               "store_path:=" + (store or "none"), "reload_stored:=" + ("true" if store else "false"),
                               "mode:=localisation", "slam_config:=" + config],
                              stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT, env=env)
    started = time.time()
    got = {}
    cond = threading.Condition()

    def on_diag(msg):
        for s in msg.status:
            if s.name.endswith(": loop_detector"):
                with cond:
                    got.update({v.key: v.value for v in s.values})
                    if float(got.get("keyframes_reloaded", -1)) == expect and float(got.get("queue_length", 1)) == 0:
                        got.setdefault("reload_s", time.time() - started)
                    cond.notify_all()
            elif s.name.endswith(": backend"):
                with cond:
                    # Its first diagnostics: the back-end is up (store restored), keyframes are mapped.
                    got.setdefault("backend_ready_s", time.time() - started)
                    got.update({"backend_" + v.key: v.value for v in s.values})
                    cond.notify_all()

    try:
        init_node("bench_paging")
        sub = rospy.Subscriber("/diagnostics", DiagnosticArray, on_diag, queue_size=100)
        with cond:
            # The loop detector holds them all, and the back-end has reported (its handover too).
            ok = cond.wait_for(lambda: "reload_s" in got and
                               float(got.get("backend_handover_keyframes_sent", -1)) == expect, timeout=600)
        elapsed = got.get("reload_s", time.time() - started)
        sub.unregister()
        if not ok:
            raise RuntimeError("the loop detector did not report %d keyframes reloaded: %s" % (expect, got))
        time.sleep(2.0)  # let freed memory settle; VmRSS is read once, after the queue emptied
        pid = pid_of("/uw_multislam/loop_detector_node")
        if pid is None:
            raise RuntimeError("no loop_detector_node process")
        return rss_kb(pid), elapsed, dict(got)
    finally:
        stop(launch)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("store", help="a store, e.g. from bench_scale --keyframes N --dir DIR --keep")
    p.add_argument("--keyframes", type=int, required=True, help="the store's keyframes")
    p.add_argument("--page-stored", choices=("true", "false", "both"), default="both",
                   help="which cases to run (default both; false keeps every feature: ~133 kB a keyframe)")
    p.add_argument("--cold", action="store_true",
                   help="drop the page cache (root: /proc/sys/vm/drop_caches) after copying the store, so the "
                        "launch reads it from the disk as after a power-up")
    a = p.parse_args()
    pages = ("true", "false") if a.page_stored == "both" else (a.page_stored,)
    tmp = tempfile.mkdtemp(prefix="uwms_bench_paging_")
    master, env = start_master()
    try:
        with open(os.path.join(rospkg.RosPack().get_path("uw_multislam"), "config", "slam.yaml")) as f:
            text = f.read()
        if "  page_stored: true " not in text:
            sys.exit("bench_paging: page_stored not in config/slam.yaml")
        configs = {}
        for page in pages:
            configs[page] = os.path.join(tmp, "slam_%s.yaml" % page)
            write_atomically(configs[page], text.replace("  page_stored: true ", "  page_stored: %s " % page))
        # A copy per run: localisation mode writes nothing, but the store's lock is per file.
        for page in pages:
            empty_kb, _, _ = run_case(None, configs[page], 0, env)
            db = os.path.join(tmp, "store_%s.db" % page)
            shutil.copy(a.store, db)
            if a.cold:
                os.sync()
                with open("/proc/sys/vm/drop_caches", "w") as f:
                    f.write("3\n")
            loaded_kb, seconds, diag = run_case(db, configs[page], a.keyframes, env)
            os.remove(db)
            print("bench_paging keyframes=%d page_stored=%s cache=%s loop_detector_rss_MB=%.1f ram_per_stored_keyframe_kB=%.2f "
                  "reload_s=%.1f keyframes_paged=%d backend_ready_s=%.1f handover_s=%.1f" % (
                      a.keyframes, page, "cold" if a.cold else "warm", loaded_kb / 1024.0,
                      (loaded_kb - empty_kb) / float(a.keyframes), seconds,
                      int(float(diag.get("keyframes_paged", 0))), float(diag.get("backend_ready_s", -1)),
                      float(diag.get("backend_handover_s", -1))), flush=True)
    finally:
        stop(master, 30)
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
