#!/usr/bin/python3
"""rostest: a parameter of the wrong type stops the node at start-up, with the key named
(ros_params::Params, typed_params.h). The test starts each standalone node itself, in a namespace
of its own, all at once:
- backend_node with a quoted datum (~datum/latitude_deg: '43', which was read as 0 degrees, the
  origin 4,800 km off): one FATAL line naming the key, before the store is opened (its file is not
  created) and before anything is advertised; the node stays up, inert, and SIGINT ends it cleanly;
- odometry_node with ~session_gap_s: '60' and loop_detector_node with ~queue_size: '100' (numbers
  as text): each exits, non-zero, after a FATAL line naming the key."""
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import unittest

import rosgraph
import rospy
import rostest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from pipeline_fixture import tool  # noqa: E402


class Node(object):
    """A standalone node started with its private parameters in namespace `ns`; its output kept."""

    def __init__(self, executable, ns, name, params):
        self.ns, self.name = ns, name
        rospy.set_param("%s/%s" % (ns, name), params)
        self.proc = subprocess.Popen([tool(executable), "__ns:=" + ns, "__name:=" + name],
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        self.lines = []
        self.reader = threading.Thread(target=lambda: self.lines.extend(self.proc.stdout), daemon=True)
        self.reader.start()

    def fatal(self):
        return [l for l in list(self.lines) if "not starting" in l]

    def wait(self, done, deadline):
        while time.time() < deadline and not done():
            time.sleep(0.1)

    def output(self):
        return "".join(self.lines)

    def stop(self):
        rospy.delete_param("%s/%s" % (self.ns, self.name))
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


class BadParamsTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="uwms_bad_params_")
        cls.store = os.path.join(cls.tmp, "sessions.db")
        # Started together: each node's start-up overlaps the others', and they share one deadline.
        cls.deadline = time.time() + 60.0
        cls.backend = Node("backend_node", "/quoted_datum", "backend_node",
                           {"store_path": cls.store, "export_root": "",
                            "datum": {"latitude_deg": "43", "longitude_deg": 5.9307}})
        cls.odometry = Node("odometry_node", "/text_gap", "odometry_node", {"session_gap_s": "60"})
        cls.loops = Node("loop_detector_node", "/text_queue", "loop_detector_node", {"queue_size": "100"})

    @classmethod
    def tearDownClass(cls):
        for node in (cls.backend, cls.odometry, cls.loops):
            node.stop()
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def test_a_quoted_datum_stops_the_backend_naming_the_key(self):
        b = self.backend
        b.wait(lambda: b.proc.poll() is not None or b.fatal(), self.deadline)
        fatal = b.fatal()
        self.assertEqual(len(fatal), 1, b.output())
        self.assertIn("/quoted_datum/backend_node/datum/latitude_deg = '43': text, not a number", fatal[0])
        self.assertFalse(os.path.exists(self.store), "the store was opened before the datum was refused")
        self.assertIsNone(b.proc.poll(), "the node died:\n" + b.output())
        # Nothing of the back-end's advertised (roscpp's own logger services aside): the FATAL line
        # comes before any publisher or service.
        state = rosgraph.Master("/check_bad_params").getSystemState()
        advertised = [name for kind in (state[0], state[2]) for name, nodes in kind
                      if "/quoted_datum/backend_node" in nodes and name.startswith("/quoted_datum/")
                      and not name.endswith(("/get_loggers", "/set_logger_level"))]
        self.assertEqual(advertised, [], b.output())
        b.proc.send_signal(signal.SIGINT)
        b.proc.wait(timeout=60)
        self.assertEqual(b.proc.returncode, 0, b.output())

    def check_exits_naming(self, node, expected):
        node.wait(lambda: node.proc.poll() is not None, self.deadline)
        self.assertIsNotNone(node.proc.poll(), "still running 60 s after start:\n" + node.output()[-2000:])
        self.assertNotEqual(node.proc.returncode, 0, node.output())
        node.reader.join(timeout=10)
        self.assertTrue(any(expected in l for l in node.fatal()), node.output())

    def test_a_number_as_text_stops_the_odometry_naming_the_key(self):
        self.check_exits_naming(self.odometry, "/text_gap/odometry_node/session_gap_s = '60': text, not a number")

    def test_a_number_as_text_stops_the_loop_detector_naming_the_key(self):
        self.check_exits_naming(self.loops, "/text_queue/loop_detector_node/queue_size = '100': text, not a number")


if __name__ == "__main__":
    rospy.init_node("check_bad_params")
    rostest.rosrun("uw_multislam", "bad_params", BadParamsTest)
