#!/usr/bin/python3
"""rostest: the back-end's start-up and shutdown. A clean shutdown loses nothing that was queued;
an unusable store leaves the node inert (and the file untouched) instead of crashing.

The back-end node (standalone, its own session store) receives N keyframes with features and a
local loop per keyframe, far faster than it stores and optimises them. As soon as its
/diagnostics say every message has been received (messages_received), it gets SIGINT. It must
then process what is still queued, save the maps and exit: the store holds all N keyframes and
all the loops, and the node's log says how many messages were still queued at the close (more
than zero, or the run did not exercise the drain: then it is repeated with more keyframes).
"""
import os
import re
import shutil
import signal
import sqlite3
import subprocess
import tempfile
import threading
import time
import unittest

import rosgraph
import rospy
import rostest
from geometry_msgs.msg import Pose2D
from pipeline_fixture import connected, status_values, synthetic_keyframe, tool
from uw_multislam.msg import Keyframe, Loop

NS = "/shutdown_test"
FEATURES = 300


def loop(k):
    """Keyframe k seen from keyframe k - 2: one metre ahead."""
    m = Loop()
    m.header.stamp = rospy.Time(1000 + k)
    m.kind = Loop.LOCAL
    m.session_a, m.keyframe_a, m.frame_a = 0, k - 2, k - 2
    m.session_b, m.keyframe_b, m.frame_b = 0, k, k
    m.pose = Pose2D(1.0, 0.0, 0.0)
    m.covariance = [1e-4, 0, 0, 0, 1e-4, 0, 0, 0, 1e-4]
    m.inliers = 100
    return m


class BackendShutdownTest(unittest.TestCase):
    def setUp(self):
        self.tmp = tempfile.mkdtemp(prefix="uwms_shutdown_")
        # One pair of publishers for every run (each run starts a fresh back-end node).
        self.kf_pub = rospy.Publisher(NS + "/keyframes", Keyframe, queue_size=100000)
        self.loop_pub = rospy.Publisher(NS + "/loops", Loop, queue_size=100000)

    def tearDown(self):
        self.kf_pub.unregister()
        self.loop_pub.unregister()
        shutil.rmtree(self.tmp, ignore_errors=True)

    def run_once(self, n):
        db = os.path.join(self.tmp, "store_%d.db" % n)
        node = subprocess.Popen([tool("backend_node"), "__ns:=" + NS, "__name:=backend_node_%d" % n, "_store_path:=" + db,
                                 "_diagnostic_period:=0.2", "_queue_size:=100000"],
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            kf_pub, loop_pub = self.kf_pub, self.loop_pub
            deadline = time.time() + 60
            while time.time() < deadline and not connected([kf_pub, loop_pub]):
                time.sleep(0.1)
            self.assertTrue(connected([kf_pub, loop_pub]), "the back-end never subscribed")
            for k in range(n):
                kf_pub.publish(synthetic_keyframe(0, k, FEATURES))
                if k >= 2:
                    loop_pub.publish(loop(k))
            expected = n + (n - 2)
            values = status_values("backend", lambda v: v.get("messages_received", -1) >= expected, 120,
                                   node="backend_node_%d" % n) or {}
            self.assertEqual(values.get("messages_received"), expected, "the back-end did not receive every message")
            node.send_signal(signal.SIGINT)
            out, _ = node.communicate(timeout=120)
        finally:
            if node.poll() is None:
                node.kill()
                node.communicate()
        self.assertEqual(node.returncode, 0, out[-3000:])
        self.assertNotIn("are not read any more", out)  # nothing under a former name of backend_node_<n>
        queued = re.search(r"unloading: (\d+) messages queued", out)
        self.assertIsNotNone(queued, "no unloading line in the back-end's output:\n" + out[-3000:])
        with sqlite3.connect(db) as c:
            keyframes = c.execute("SELECT COUNT(*) FROM keyframes").fetchone()[0]
            loops = c.execute("SELECT COUNT(*) FROM loops").fetchone()[0]
            maps = c.execute("SELECT COUNT(*) FROM maps").fetchone()[0]
        return int(queued.group(1)), keyframes, loops, maps

    def test_an_unusable_store_leaves_the_node_inert_and_the_file_untouched(self):
        """1 MB of random bytes as the store: a FATAL line naming the file, no service advertised,
        the process keeps running (it used to take the whole nodelet manager down with a SIGSEGV),
        SIGINT ends it cleanly, and the file is byte-identical."""
        junk = os.path.join(self.tmp, "junk.db")
        data = os.urandom(1 << 20)
        with open(junk, "wb") as f:
            f.write(data)
        ns = NS + "_junk"
        # An old config file's block: the node was named backend before; it warns once that these
        # are not read any more.
        rospy.set_param(ns + "/backend", {"queue_size": 5, "publish_tf": False})
        node = subprocess.Popen([tool("backend_node"), "__ns:=" + ns, "__name:=backend_node", "_store_path:=" + junk],
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        lines = []
        reader = threading.Thread(target=lambda: lines.extend(node.stdout), daemon=True)
        reader.start()
        try:
            master = rosgraph.Master("/check_backend_shutdown")
            deadline = time.time() + 60
            while time.time() < deadline and not any("not starting" in l for l in lines):
                time.sleep(0.1)
            self.assertTrue(any("not starting" in l and junk in l for l in lines), "".join(lines))
            warned = [l for l in lines if "are not read any more" in l]
            self.assertEqual(len(warned), 1, "".join(lines))
            self.assertIn("parameters under %s/backend are not read any more: this node's parameters are "
                          "%s/backend_node/..." % (ns, ns), warned[0])
            self.assertIn("publish_tf, queue_size", warned[0])
            self.assertIsNone(node.poll(), "the node died:\n" + "".join(lines))
            ours = ("join_sessions", "split_session", "list_sessions", "start_session", "reload_session")
            services = [name for name, _ in master.getSystemState()[2] if name.rsplit("/", 1)[-1] in ours
                        and name.startswith(ns + "/")]
            self.assertEqual(services, [], "services advertised over an unusable store")
            node.send_signal(signal.SIGINT)
            node.wait(timeout=60)
        finally:
            rospy.delete_param(ns + "/backend")
            if node.poll() is None:
                node.kill()
                node.wait()
        self.assertEqual(node.returncode, 0, "".join(lines))
        with open(junk, "rb") as f:
            self.assertEqual(f.read(), data, "the refused store was modified")

    def test_queued_keyframes_and_loops_are_stored_at_a_clean_shutdown(self):
        for n in (300, 1000, 3000):
            queued, keyframes, loops, maps = self.run_once(n)
            print("n %d: %d messages queued at SIGINT; stored %d keyframes, %d loops, %d maps"
                  % (n, queued, keyframes, loops, maps), flush=True)
            self.assertEqual(keyframes, n, "keyframes lost at shutdown")
            self.assertEqual(loops, n - 2, "loops lost at shutdown")
            self.assertEqual(maps, 1, "the maps were not saved at shutdown")
            if queued > 0:
                return
        self.fail("the back-end never had a backlog at SIGINT: the drain was not exercised")


if __name__ == "__main__":
    rospy.init_node("check_backend_shutdown")
    rostest.rosrun("uw_multislam", "check_backend_shutdown", BackendShutdownTest)
