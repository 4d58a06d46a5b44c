#!/usr/bin/python3
"""Relays a DVL driver's altitude as sensor_msgs/Range (onboard.launch starts it for dvl:=TOPIC):
each message on the DVL's topic (any message type with a header) becomes a Range on `dvl_altitude`
in this node's namespace, with the message's stamp, its header.frame_id (or --frame) and the range
the expression gives. A reading <= 0 (no bottom lock) is relayed as it is: the odometry refuses it
like a bad range.

    dvl_altitude.py --input /dvl/data --expression m.pose.pose.position.z [--frame dvl_link]

--input TOPIC        the DVL's topic; its type is taken from the first message (rospy.AnyMsg).
--expression EXPR    Python expression of the altitude above the seabed in metres, in the message m
                     (m.altitude, m.pose.pose.position.z); `math` may be used. A syntax error stops
                     the node at start-up with one line.
--frame FRAME        the frame_id of the Ranges; `header` (the default): the message's own.
--error-period S     at most one error line per S seconds (default 10).

A message the expression cannot be read from (a field its type lacks, a value that is not a number)
is dropped with one ERROR naming the expression, the field, the message type and the fields it does
have; while the error lasts, one more line at most every --error-period seconds with the count of
messages dropped. No traceback per message.
"""
import argparse
import math
import sys
import time

import roslib.message
import rospy
from sensor_msgs.msg import Range
from std_msgs.msg import Header

Message = roslib.message.Message  # genpy's, every message's base

MAX_LISTED_FIELDS = 40
NUMERIC_TYPES = {"float32", "float64", "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32", "uint64",
                 "byte", "char"}


def numeric_fields(msg, prefix="m"):
    """The paths of the numbers a message holds, as an expression names them (arrays as [i])."""
    out = []
    for name, kind in zip(msg.__slots__, msg._slot_types):
        value = getattr(msg, name)
        path = "%s.%s" % (prefix, name)
        if isinstance(value, Message):
            out += numeric_fields(value, path)
        elif kind in ("time", "duration"):
            out.append(path)
        elif kind.endswith("]") and kind.split("[")[0] in NUMERIC_TYPES:
            out.append("%s[i]" % path)
        elif kind in NUMERIC_TYPES:
            out.append(path)
    return out



def path_of(obj, msg, prefix="m"):
    """Where `obj` (a sub-message) sits in `msg`, as an expression names it; None when it does not."""
    if obj is msg:
        return prefix
    for name in getattr(msg, "__slots__", ()):
        value = getattr(msg, name)
        if isinstance(value, Message):
            found = path_of(obj, value, "%s.%s" % (prefix, name))
            if found:
                return found
    return None


class RelayError(Exception):
    """Why one message could not be relayed (one line)."""


class AltitudeRelay:
    """The conversion of one DVL message into a Range, by the expression (the node's work, without ROS I/O)."""

    def __init__(self, expression, frame="header"):
        self.expression = expression
        try:
            self.code = compile(expression, "<dvl_altitude expression>", "eval")
        except SyntaxError as e:
            raise ValueError("dvl_altitude: the expression '%s' is not Python: %s" % (expression, e.msg)) from None
        self.frame = frame

    def describe(self, msg):
        fields = numeric_fields(msg)
        listed = ", ".join(fields[:MAX_LISTED_FIELDS]) + (", ..." if len(fields) > MAX_LISTED_FIELDS else "")
        return "%s's numeric fields: %s" % (msg._type, listed or "none")

    def range_of(self, msg):
        """The Range for `msg`; RelayError naming the field at fault and the type's fields."""
        try:
            value = eval(self.code, {"math": math}, {"m": msg})
        except AttributeError as e:
            owner = getattr(e, "obj", None)
            if isinstance(owner, Message):
                where = path_of(owner, msg) or owner._type
                raise RelayError("dvl_altitude: the expression '%s' reads '%s', which %s (%s) does not have (its "
                                 "fields: %s); %s" % (self.expression, e.name, where, owner._type,
                                                      ", ".join(owner.__slots__), self.describe(msg))) from None
            raise RelayError("dvl_altitude: the expression '%s' failed on %s: %s; %s" % (
                self.expression, msg._type, e, self.describe(msg))) from None
        except Exception as e:  # an index, a name, a division: the expression's own error, said once
            raise RelayError("dvl_altitude: the expression '%s' failed on %s: %s: %s; %s" % (
                self.expression, msg._type, type(e).__name__, e, self.describe(msg))) from None
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise RelayError("dvl_altitude: the expression '%s' gives %s, not a number of metres; %s" % (
                self.expression, getattr(value, "_type", type(value).__name__), self.describe(msg)))
        header = getattr(msg, "header", None)
        if not isinstance(header, Header):
            raise RelayError("dvl_altitude: %s has no header (its fields: %s): the Range needs the reading's stamp"
                             % (msg._type, ", ".join(msg.__slots__)))
        frame = header.frame_id if self.frame == "header" else self.frame
        return Range(header=Header(stamp=header.stamp, frame_id=frame), radiation_type=Range.INFRARED,
                     min_range=0.0, max_range=1000.0, range=float(value))


class ErrorThrottle:
    """The first error at once, then at most one line every `period_s` with the count dropped meanwhile."""

    def __init__(self, period_s, clock=time.monotonic):
        self.period_s = period_s
        self.clock = clock
        self.last = None
        self.dropped = 0  # messages dropped since the last line

    def line(self, text):
        """The line to log for this error, or None while throttled."""
        self.dropped += 1
        now = self.clock()
        if self.last is not None and now - self.last < self.period_s:
            return None
        first = self.last is None
        self.last, dropped, self.dropped = now, self.dropped, 0
        return text if first else "%s (%d messages dropped in the last %.0f s)" % (text, dropped, self.period_s)


def main(argv):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog=__doc__.split("\n\n", 1)[1],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--input", required=True, metavar="TOPIC", help="the DVL's topic")
    parser.add_argument("--expression", default="m.altitude", metavar="EXPR",
                        help="the altitude in metres in the message m (default m.altitude)")
    parser.add_argument("--frame", default="header", help="the Ranges' frame_id (default: the message's own)")
    parser.add_argument("--error-period", type=float, default=10.0, metavar="S",
                        help="at most one error line per S seconds (default 10)")
    args = parser.parse_args(rospy.myargv(argv)[1:])
    try:
        relay = AltitudeRelay(args.expression, args.frame)
    except ValueError as e:
        print(e, file=sys.stderr)
        return 2
    throttle = ErrorThrottle(args.error_period)
    rospy.init_node("dvl_altitude")
    pub = rospy.Publisher("dvl_altitude", Range, queue_size=10)
    classes = {}

    def on_message(raw):
        kind = raw._connection_header["type"]
        if kind not in classes:
            classes[kind] = roslib.message.get_message_class(kind)
        try:
            if classes[kind] is None:
                raise RelayError("dvl_altitude: %s: message type %s is not known here (its package is not "
                                 "built or sourced)" % (args.input, kind))
            msg = classes[kind]().deserialize(raw._buff)
            pub.publish(relay.range_of(msg))
        except RelayError as e:
            line = throttle.line(str(e))
            if line:
                rospy.logerr(line)

    rospy.Subscriber(args.input, rospy.AnyMsg, on_message, queue_size=10)
    rospy.loginfo("dvl_altitude: %s -> %s, altitude %s, frame %s", rospy.resolve_name(args.input),
                  rospy.resolve_name("dvl_altitude"), args.expression,
                  "the messages' own" if args.frame == "header" else args.frame)
    rospy.spin()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
