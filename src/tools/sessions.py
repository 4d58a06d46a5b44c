#!/usr/bin/python3
"""Calls the session manager's services and prints each answer on a few short lines
(rosservice call prints the same in YAML).

    sessions.py list
    sessions.py join A B [MIN_LOOPS]      (MIN_LOOPS 0: the back-end's K)
    sessions.py split S
    sessions.py start [NAME]
    sessions.py reload NAME               (a stored session's name or id, back into memory)
    sessions.py unload NAME               (a reloaded stored session out of memory again: UNLOADED)
    sessions.py delete NAME [confirm]     (delete_session: from the store for good; without `confirm`
                                           the back-end answers what would go and deletes nothing)
    sessions.py finish                    (ends the recording session; none starts until start or resume)
    sessions.py pause                     (the odometry drops frames, counted, until resume)
    sessions.py resume
    sessions.py link A KA B KB X Y YAW SIGMA_XY SIGMA_YAW [INLIERS]
                                          (add_link: keyframe KB of session B at (X, Y, YAW) in keyframe KA
                                           of session A, metres and radians, diagonal covariance)
    sessions.py find A KA B KB            (add_link "find it": RANSAC between two stored keyframes)
    sessions.py optimise                  (optimises now the maps whose loops wait)
    sessions.py detect S1 S2 [S3 ...]     (detect_loops among stored sessions, each against those before it)
    sessions.py mode mapping|localisation (set_mode: localisation writes nothing to the store)
    sessions.py history [N]               (the audit trail: joins, splits, links, deletions, mode changes;
                                           the last N entries, default all)

Exit status: 0 when the service answered OK, 3 when it refused the request (the answer, with its
status code and message, is printed as for OK), 1 when it could not be called (no master, or no
back-end within --timeout), 2 for wrong arguments.
"""
import argparse
import sys

# --help works without a sourced workspace (setup.bash puts the package's messages on PYTHONPATH);
# any command without them stops with a line that says so.
try:
    import rosgraph
    import rospy
    from uw_multislam.msg import SessionState, Status
    from geometry_msgs.msg import Pose2D
    from uw_multislam.srv import (AddLink, DeleteSession, DetectLoops, FinishSession, History, JoinSessions, ListSessions, OperatorCommand,
                                  Optimise, ReloadSession, SetMode, SplitSession, StartSession)
    ROS_IMPORT_ERROR = None
except ImportError as e:
    ROS_IMPORT_ERROR = e


def constants(kind):
    return {v: k for k, v in vars(kind).items() if k.isupper() and isinstance(v, int)}


def status_text(status):
    text = constants(Status).get(status.code, str(status.code))
    return text + (": " + status.message if status.message else "")


REFUSED = 3  # the exit status when the back-end answered with another code than OK

# command -> (fewest, most) arguments
ARITY = {"list": (0, 0), "join": (2, 3), "split": (1, 1), "start": (0, 1), "reload": (1, 1), "unload": (1, 1), "delete": (1, 2), "pause": (0, 0),
         "resume": (0, 0), "finish": (0, 0), "link": (9, 10), "optimise": (0, 0),
         "detect": (2, 1000), "mode": (1, 1), "find": (4, 4), "history": (0, 1)}


def call_service(ns, name, kind, *request, timeout=30.0):
    if not rosgraph.is_master_online():  # rospy would fail with "time is not initialized"
        raise rospy.ROSException("no ROS master at %s (is the SLAM running? ROS_MASTER_URI)" % rosgraph.get_master_uri())
    service = "%s/%s" % (ns.rstrip("/"), name)
    rospy.wait_for_service(service, timeout=timeout)
    return rospy.ServiceProxy(service, kind)(*request)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ns", default="/uw_multislam", help="namespace of the back-end's services")
    parser.add_argument("--timeout", type=float, default=30.0, help="seconds to wait for the service (default 30)")
    parser.add_argument("command", choices=tuple(ARITY))
    parser.add_argument("args", nargs="*")
    args = parser.parse_args()
    if ROS_IMPORT_ERROR:
        print("sessions.py: %s (source the workspace's devel/setup.bash or install/setup.bash first)" %
              ROS_IMPORT_ERROR, file=sys.stderr)
        return 1
    fewest, most = ARITY[args.command]
    if not fewest <= len(args.args) <= most:
        parser.error("%s takes %s argument(s), got %d: %s" % (
            args.command, fewest if fewest == most else "%d to %d" % (fewest, most), len(args.args), args.args))

    def call(ns, name, kind, *request):
        return call_service(ns, name, kind, *request, timeout=args.timeout)

    try:
        if args.command == "list":
            res = call(args.ns, "list_sessions", ListSessions)
            print("list_sessions -> %s, %d sessions" % (status_text(res.status), len(res.sessions)))
            for s in res.sessions:
                print("  session %d %-10s %-8s map %d  %4d keyframes  %3d loops%s%s" % (
                    s.session, s.name, constants(SessionState).get(s.state, str(s.state)), s.map, s.num_keyframes,
                    s.num_loops,
                    "  relocalised in map %d" % s.relocalised_map if s.relocalised_map >= 0 else "",
                    "  from vehicle %s" % s.vehicle if getattr(s, "vehicle", "") else ""))
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
        elif args.command == "reload":
            name = args.args[0]
            res = call(args.ns, "reload_session", ReloadSession, name)
            print("reload_session '%s' -> %s%s" % (name, status_text(res.status),
                                                  ", session %d" % res.session if res.status.code == Status.OK else ""))
        elif args.command == "unload":
            name = args.args[0]
            res = call(args.ns, "unload_session", ReloadSession, name)
            print("unload_session '%s' -> %s%s" % (name, status_text(res.status),
                                                  ", session %d" % res.session if res.status.code == Status.OK else ""))
        elif args.command == "delete":
            name = args.args[0]
            if len(args.args) > 1 and args.args[1] != "confirm":
                raise ValueError("the second argument can only be the word confirm")
            res = call(args.ns, "delete_session", DeleteSession, name, len(args.args) > 1)
            print("delete_session '%s'%s -> %s%s" % (name, " confirm" if len(args.args) > 1 else "",
                                                    status_text(res.status),
                                                    ", session %d" % res.session if res.status.code == Status.OK else ""))
        elif args.command == "finish":
            res = call(args.ns, "finish_session", FinishSession)
            print("finish_session -> %s%s" % (status_text(res.status),
                                               ", session %d" % res.session if res.status.code == Status.OK else ""))
        elif args.command == "link":
            a, ka, b, kb = (int(v) for v in args.args[:4])
            x, y, yaw, sxy, syaw = (float(v) for v in args.args[4:9])
            inliers = int(args.args[9]) if len(args.args) > 9 else 0
            if not (sxy > 0 and syaw > 0):
                raise ValueError("the sigmas must be positive")
            covariance = [sxy * sxy, 0, 0, 0, sxy * sxy, 0, 0, 0, syaw * syaw]
            res = call(args.ns, "add_link", AddLink, a, ka, b, kb, Pose2D(x, y, yaw), covariance, inliers, False)
            print("add_link %d:%d -> %d:%d -> %s" % (a, ka, b, kb, status_text(res.status)))
        elif args.command == "find":
            a, ka, b, kb = (int(v) for v in args.args)
            res = call(args.ns, "add_link", AddLink, a, ka, b, kb, Pose2D(), [0.0] * 9, 0, True)
            print("add_link find %d:%d -> %d:%d -> %s%s" % (
                a, ka, b, kb, status_text(res.status), ", pose (%.3f, %.3f, %.4f), %d inliers" % (
                    res.pose.x, res.pose.y, res.pose.theta, res.inliers) if res.status.code == Status.OK else ""))
        elif args.command == "optimise":
            res = call(args.ns, "optimise", Optimise)
            print("optimise -> %s, %d maps due" % (status_text(res.status), res.maps))
        elif args.command == "detect":
            sessions = [int(v) for v in args.args]
            res = call(args.ns, "detect_loops", DetectLoops, sessions)
            print("detect_loops %s -> %s; %d keyframes queried, %d candidates, %d loops (%d held already), "
                  "%d accepted, %d refused, %d joins" % (
                      " ".join(map(str, sessions)), status_text(res.status), res.queries, res.candidates, res.found,
                      res.already_held, res.accepted, res.refused, res.joins))
        elif args.command == "mode":
            res = call(args.ns, "set_mode", SetMode, args.args[0])
            print("set_mode %s -> %s, %s mode" % (args.args[0], status_text(res.status), res.mode))
        elif args.command == "history":
            last = int(args.args[0]) if args.args else 0
            res = call(args.ns, "history", History, last)
            print("history -> %s, %d entries" % (status_text(res.status), len(res.entries)))
            for e in res.entries:
                print("  #%d %s %-6s %-9s %s%s" % (e.id, e.time_utc, e.kind, e.cause, e.message,
                                                   "; loops " + e.loops if e.loops else ""))
        elif args.command in ("pause", "resume"):
            res = call(args.ns, args.command, OperatorCommand)
            print("%s -> %s, %s, %d frames dropped while paused" % (
                args.command, status_text(res.status), "paused" if res.paused else "running", res.frames_dropped_paused))
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
    return 0 if res.status.code == Status.OK else REFUSED


if __name__ == "__main__":
    sys.exit(main())
