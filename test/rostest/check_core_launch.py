#!/usr/bin/python3
"""rostest: core.launch brings up the nodelet manager and loads config/default.yaml; slam.launch
loads the pipeline's nodelets into it, by the names the launch file gives them."""
import os
import time
import unittest

import rospy
import rostest
import yaml
from nodelet.srv import NodeletList

PKG_DIR = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

# Each manager's nodelets once slam.launch has loaded them (core_launch.test).
EXPECTED = {
    "/uw_multislam/manager": {"/uw_multislam/odometry_node", "/uw_multislam/loop_detector_node",
                              "/uw_multislam/backend_node"},
    "/split/manager": {"/split/odometry_node", "/split/local_loops_node", "/split/global_loops_node",
                       "/split/backend_node"},
}


class CoreLaunchTest(unittest.TestCase):
    def loaded(self, manager, expected, timeout=60.0):
        """The manager's nodelets once they equal `expected`, or the last list at the deadline (the
        nodelet loaders call the manager in their own time)."""
        name = manager + "/list"
        rospy.wait_for_service(name, timeout=timeout)
        listing = rospy.ServiceProxy(name, NodeletList)
        deadline = time.time() + timeout
        while True:
            got = set(listing().nodelets)
            if got == expected or time.time() > deadline:
                return got
            time.sleep(0.2)

    def test_the_managers_hold_the_pipelines_nodelets(self):
        for manager, expected in EXPECTED.items():
            self.assertEqual(self.loaded(manager, expected), expected, manager)

    def test_parameters_match_default_yaml(self):
        with open(os.path.join(PKG_DIR, "config", "default.yaml")) as f:
            expected = yaml.safe_load(f)
        self.assertIn("frames", expected)
        loaded = rospy.get_param("/uw_multislam")
        for block, values in expected.items():
            self.assertIn(block, loaded, "parameter block %s not loaded" % block)
            for key, value in values.items():
                self.assertEqual(loaded[block][key], value, "%s/%s" % (block, key))


if __name__ == "__main__":
    rospy.init_node("check_core_launch")
    rostest.rosrun("uw_multislam", "check_core_launch", CoreLaunchTest)
