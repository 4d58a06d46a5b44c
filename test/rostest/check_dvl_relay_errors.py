#!/usr/bin/python3
"""rostest: the DVL relay with a wrong field (dvl_relay_errors.test). nav_msgs/Odometry stands in for
the driver's message; the expression reads pose.pose.position.zz. A burst of 8 messages, then one
every 0.1 s until the relay's second error line: the first line names the field, where it is
missed (geometry_msgs/Point) and its fields; the second (after --error-period 1) counts the
messages dropped since; nothing else from the relay at ERROR, no traceback, no Range relayed.
"""
import threading
import time
import unittest

import rospy
import rostest
from nav_msgs.msg import Odometry
from pipeline_fixture import NS, await_condition, connected, publisher_connected, wait_for_subscribers
from rosgraph_msgs.msg import Log
from sensor_msgs.msg import Range

RELAY = NS + "/dvl_altitude"
BURST = 8


class DvlRelayErrorsTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.lock = threading.Lock()
        cls.logs, cls.ranges = [], []

        def on_log(msg):
            if msg.name == RELAY:
                with cls.lock:
                    cls.logs.append(msg)

        def on_range(msg):
            with cls.lock:
                cls.ranges.append(msg)

        cls.subs = [rospy.Subscriber("/rosout", Log, on_log, queue_size=1000),
                    rospy.Subscriber(RELAY, Range, on_range, queue_size=100)]
        cls.pub = rospy.Publisher("/dvl/data", Odometry, queue_size=100)
        wait_for_subscribers(["/dvl/data"], "/check_dvl_relay_errors")
        cls.wait(lambda: connected([cls.pub]) and publisher_connected(RELAY, "/rosout"), 30.0,
                 "the connections to the relay")
        cls.published = 0
        for _ in range(BURST):
            cls.send()
        cls.wait(lambda: len(cls.errors()) >= 1, 30.0, "the relay's first error")
        deadline = time.time() + 30.0
        while time.time() < deadline:
            with cls.lock:
                if len(cls.errors()) >= 2:
                    break
            cls.send()
            time.sleep(0.1)  # the pace of a DVL (10 Hz), not a wait for a result
        with cls.lock:
            cls.final_logs, cls.final_ranges = list(cls.logs), list(cls.ranges)

    @classmethod
    def send(cls):
        m = Odometry()
        m.header.stamp = rospy.Time.now()
        m.header.frame_id = "dvl_link"
        m.pose.pose.position.z = 2.0
        cls.pub.publish(m)
        cls.published += 1

    @classmethod
    def errors(cls):
        return [log for log in cls.logs if log.level >= Log.ERROR]

    @classmethod
    def wait(cls, condition, timeout, what):
        await_condition(cls.lock, condition, timeout, what,
                        lambda: "; the relay said: %s" % [log.msg for log in cls.logs])

    def test_one_error_names_the_field_then_one_a_period_with_the_count(self):
        errors = [log.msg for log in self.final_logs if log.level >= Log.ERROR]
        self.assertEqual(len(errors), 2, errors)
        self.assertTrue(errors[0].startswith(
            "dvl_altitude: the expression 'm.pose.pose.position.zz * 1.0' reads 'zz', which m.pose.pose.position "
            "(geometry_msgs/Point) does not have (its fields: x, y, z); nav_msgs/Odometry's numeric fields: "),
            errors[0])
        self.assertIn("m.pose.pose.position.z, ", errors[0])
        head, _, count = errors[1].rpartition(" (")
        self.assertEqual(head, errors[0])
        dropped = int(count.split()[0])
        self.assertTrue(count.endswith("messages dropped in the last 1 s)"), count)
        # The burst's other 7 and at least the one that ended the period; no more than were sent.
        self.assertGreaterEqual(dropped, BURST)
        self.assertLessEqual(dropped + 1, self.published)

    def test_no_traceback_and_nothing_relayed(self):
        for log in self.final_logs:
            self.assertNotIn("Traceback", log.msg)
            self.assertNotIn("bad callback", log.msg)
        self.assertEqual(self.final_ranges, [])


if __name__ == "__main__":
    rospy.init_node("check_dvl_relay_errors")
    rostest.rosrun("uw_multislam", "check_dvl_relay_errors", DvlRelayErrorsTest)
