#!/usr/bin/python3
"""Calls the session manager's services and prints each answer on a few short lines
(rosservice call prints the same in YAML).

    sessions.py list
    sessions.py join A B [MIN_LOOPS]      (MIN_LOOPS 0: the back-end's K)
    sessions.py split S
    sessions.py start [NAME]

Exit status: 0 when the service answered (whatever its status code: the answer is printed),
1 when it could not be called.
"""
import argparse
import sys

# --help works without a sourced workspace (setup.bash puts the package's messages on PYTHONPATH);
# any command without them stops with a line that says so.
try:
    import rospy
    from uw_multislam.msg import SessionState, Status
    from uw_multislam.srv import JoinSessions, ListSessions, SplitSession, StartSession
    ROS_IMPORT_ERROR = None
except ImportError as e:
    ROS_IMPORT_ERROR = e


def constants(kind):
    return {v: k for k, v in vars(kind).items() if k.isupper() and isinstance(v, int)}


def status_text(status):
    text = constants(Status).get(status.code, str(status.code))
    return text + (": " + status.message if status.message else "")


def call(ns, name, kind, *request):
    service = "%s/%s" % (ns.rstrip("/"), name)
    rospy.wait_for_service(service, timeout=30.0)
    return rospy.ServiceProxy(service, kind)(*request)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ns", default="/uw_multislam")
    parser.add_argument("command", choices=("list", "join", "split", "start"))
    parser.add_argument("args", nargs="*")
    args = parser.parse_args()
    if ROS_IMPORT_ERROR:
        print("sessions.py: %s (source the workspace's devel/setup.bash or install/setup.bash first)" %
              ROS_IMPORT_ERROR, file=sys.stderr)
        return 1
    try:
        if args.command == "list":
            res = call(args.ns, "list_sessions", ListSessions)
            print("list_sessions -> %s, %d sessions" % (status_text(res.status), len(res.sessions)))
            for s in res.sessions:
                print("  session %d %-10s %-8s map %d  %4d keyframes  %3d loops" % (
                    s.session, s.name, constants(SessionState).get(s.state, str(s.state)), s.map, s.num_keyframes,
                    s.num_loops))
        elif args.command == "join":
            a, b = int(args.args[0]), int(args.args[1])
            k = int(args.args[2]) if len(args.args) > 2 else 0
            res = call(args.ns, "join_sessions", JoinSessions, a, b, k)
            print("join_sessions %d %d %d -> %s%s" % (a, b, k, status_text(res.status),
                                                     ", map %d" % res.map if res.status.code == Status.OK else ""))
        elif args.command == "split":
            s = int(args.args[0])
            res = call(args.ns, "split_session", SplitSession, s)
            print("split_session %d -> %s" % (s, status_text(res.status)))
        else:
            name = args.args[0] if args.args else ""
            res = call(args.ns, "start_session", StartSession, name)
            print("start_session '%s' -> %s%s" % (name, status_text(res.status),
                                                 ", session %d" % res.session if res.status.code == Status.OK else ""))
    except (IndexError, ValueError):
        parser.error("%s: wrong arguments %s" % (args.command, args.args))
    except (rospy.ROSException, rospy.ServiceException) as e:
        print("sessions.py %s: %s" % (args.command, e), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
