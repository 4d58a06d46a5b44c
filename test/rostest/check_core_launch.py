#!/usr/bin/python3
"""rostest: core.launch brings up the nodelet manager and loads config/default.yaml."""
import os
import unittest

import rospy
import rostest
import yaml
from nodelet.srv import NodeletList

PKG_DIR = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


class CoreLaunchTest(unittest.TestCase):
    def test_manager_answers(self):
        name = "/uw_multislam/manager/list"
        rospy.wait_for_service(name, timeout=30.0)
        reply = rospy.ServiceProxy(name, NodeletList)()
        self.assertIsInstance(reply.nodelets, list)

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
