#!/usr/bin/python3
"""Prints the latest uw_multislam statuses from /diagnostics as one JSON object
{"<status name>": {"level": L, "message": M, "<key>": value, ...}, ...}.

usage: diagnostics_snapshot.py [--wait S] [--match TEXT]
  --wait S      listen this long (default 3 s; statuses come every diagnostic_period)
  --match TEXT  keep statuses whose name contains TEXT (default "uw_multislam")
"""
import argparse
import json
import sys
import time

import rospy
from diagnostic_msgs.msg import DiagnosticArray


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--wait", type=float, default=3.0)
    ap.add_argument("--match", default="uw_multislam")
    args = ap.parse_args(rospy.myargv()[1:])
    latest = {}

    def on_array(msg):
        for s in msg.status:
            if args.match in s.name:
                entry = {"level": int.from_bytes(s.level, "little") if isinstance(s.level, bytes) else int(s.level),
                         "message": s.message}
                for kv in s.values:
                    try:
                        entry[kv.key] = float(kv.value)
                    except ValueError:
                        entry[kv.key] = kv.value
                latest[s.name] = entry

    rospy.init_node("diagnostics_snapshot", anonymous=True, disable_signals=True)
    rospy.Subscriber("/diagnostics", DiagnosticArray, on_array, queue_size=100)
    deadline = time.time() + args.wait
    while time.time() < deadline and not rospy.is_shutdown():
        time.sleep(0.1)
    json.dump(latest, sys.stdout, indent=1, sort_keys=True)
    print()
    return 0 if latest else 1


if __name__ == "__main__":
    sys.exit(main())
