"""scripts/dvl_altitude.py without a ROS master: the Range made from a DVL message by the expression,
the one-line errors naming the field and the type's fields, and their throttle. The relay in
onboard.launch, live: rostest dvl_altitude (a good expression) and dvl_relay_errors (a wrong field)."""
import importlib.util
import os
import subprocess

import pytest
import rospy
from geometry_msgs.msg import Point
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Range

TOOL = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "scripts", "dvl_altitude.py")
_spec = importlib.util.spec_from_file_location("dvl_altitude", TOOL)
dvl = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(dvl)


def odometry(z, frame="odom", secs=12):
    m = Odometry()
    m.header.stamp = rospy.Time(secs, 500)
    m.header.frame_id = frame
    m.pose.pose.position.z = z
    return m


def test_the_range_takes_the_stamp_frame_and_value():
    r = dvl.AltitudeRelay("m.pose.pose.position.z").range_of(odometry(2.25))
    assert isinstance(r, Range)
    assert (r.header.stamp, r.header.frame_id, r.range) == (rospy.Time(12, 500), "odom", 2.25)
    assert (r.min_range, r.max_range) == (0.0, 1000.0)
    r = dvl.AltitudeRelay("m.pose.pose.position.z * 0.5 + 0.1", frame="dvl_link").range_of(odometry(2.0))
    assert (r.header.frame_id, r.range) == ("dvl_link", pytest.approx(1.1))
    assert dvl.AltitudeRelay("m.pose.pose.position.z").range_of(odometry(0.0)).range == 0.0  # refused downstream


def test_a_wrong_field_names_it_its_owner_and_the_fields_there_are():
    with pytest.raises(dvl.RelayError) as e:
        dvl.AltitudeRelay("m.pose.pose.position.zz").range_of(odometry(2.0))
    text = str(e.value)
    assert text.startswith("dvl_altitude: the expression 'm.pose.pose.position.zz' reads 'zz', which "
                           "m.pose.pose.position (geometry_msgs/Point) does not have (its fields: x, y, z); "
                           "nav_msgs/Odometry's numeric fields: m.header.seq, m.header.stamp, "), text
    assert "m.pose.pose.position.z, " in text and "m.pose.covariance[i]" in text and "\n" not in text
    with pytest.raises(dvl.RelayError, match=r"reads 'altitude', which m \(nav_msgs/Odometry\) does not have "
                                             r"\(its fields: header, child_frame_id, pose, twist\)"):
        dvl.AltitudeRelay("m.altitude").range_of(odometry(2.0))


def test_other_failures_are_one_line_too():
    cases = [("m.pose.pose.position", "gives geometry_msgs/Point, not a number of metres"),
             ("m.pose.covariance[99]", "failed on nav_msgs/Odometry: IndexError: "),
             ("altitude", "failed on nav_msgs/Odometry: NameError: name 'altitude' is not defined"),
             ("m.child_frame_id", "gives str, not a number")]
    for expression, words in cases:
        with pytest.raises(dvl.RelayError) as e:
            dvl.AltitudeRelay(expression).range_of(odometry(2.0))
        assert words in str(e.value) and "\n" not in str(e.value), (expression, str(e.value))
    with pytest.raises(dvl.RelayError, match=r"geometry_msgs/Point has no header \(its fields: x, y, z\)"):
        dvl.AltitudeRelay("m.z").range_of(Point(z=1.0))
    with pytest.raises(ValueError, match=r"the expression 'm\.\(' is not Python: invalid syntax"):
        dvl.AltitudeRelay("m.(")


def test_errors_are_said_once_then_at_most_once_a_period_with_the_count():
    now = [100.0]
    throttle = dvl.ErrorThrottle(10.0, clock=lambda: now[0])
    lines = []
    for _ in range(30):  # 30 messages at 10 Hz
        lines.append(throttle.line("bad"))
        now[0] += 0.1
    said = [line for line in lines if line]
    assert said == ["bad"]
    now[0] = 110.05
    assert throttle.line("bad") == "bad (30 messages dropped in the last 10 s)"
    assert throttle.line("bad") is None


def test_a_syntax_error_stops_the_node_with_one_line():
    r = subprocess.run(["/usr/bin/python3", TOOL, "--input", "/dvl/data", "--expression", "m.("], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        "dvl_altitude: the expression 'm.(' is not Python: invalid syntax"]
