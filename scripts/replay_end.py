#!/usr/bin/python3
"""Ends replay.launch when its bags end, once the pipeline has finished with them.

rosbag play exits at the end of its bags, but the pipeline is still busy then: frames wait in the
odometry's queue, keyframes and loops in the loop detectors' and the back-end's, and the back-end
optimises every optimise_every loops, so the last ones may wait. Shutting down at once would lose
them (a nodelet cannot publish once ROS is shutting down). This node, started by replay.launch
with required="true", therefore:
  1. waits for the player (--player) to register with the master and then to leave it;
  2. waits until the pipeline is idle: on /diagnostics, every odometry, loop detector and back-end
     status under --ns has an empty queue (the odometry: every frame it took finished, no image
     waiting for its camera_info or altitude) and their counters of frames, keyframes, loops and
     optimisations have not moved for --quiet-s seconds, over at least two statuses of each;
  3. asks the back-end to optimise what is pending (its optimise service) and waits for idle again;
  4. says so and exits, and roslaunch, the node being required, stops everything: the back-end
     saves its maps and closes its session store as it unloads.
With --stay-up it says so after step 2 and keeps running (for rviz): Ctrl-C ends the replay.
Wall time throughout: under use_sim_time the clock stops with the bag.
"""
import argparse
import sys
import threading
import time
import xmlrpc.client

import rosgraph
import rospy
from diagnostic_msgs.msg import DiagnosticArray
from uw_multislam.srv import Optimise

POLL_S = 0.2
# Per status kind: the counters that move while work is in flight, and those that must be 0 when idle.
MOVING = {
    "odometry": ("images_received", "frames_processed", "frames_finished", "keyframes"),
    "loop_detector": ("keyframes_received", "local_loops", "global_loops", "dropped_queue_full"),
    "backend": ("messages_received", "keyframes_received", "loops_received", "optimisations"),
}
EMPTY = {"odometry": ("queue_length", "images_waiting_pairing"), "loop_detector": ("queue_length",),
         "backend": ("queue_length",)}


class Pipeline:
    """The latest /diagnostics status of each of the pipeline's nodes under a namespace."""

    def __init__(self, ns):
        self.prefix = ns.strip("/") + "/"  # diagnostic_updater names a status without the leading /
        self.lock = threading.Lock()
        self.values = {}  # status name -> (kind, {key: value})
        self.arrivals = {}  # status name -> statuses received
        rospy.Subscriber("/diagnostics", DiagnosticArray, self.on_diagnostics, queue_size=100)

    def on_diagnostics(self, msg):
        with self.lock:
            for s in msg.status:
                name, _, kind = s.name.rpartition(": ")
                if name.lstrip("/").startswith(self.prefix) and kind in MOVING:
                    self.values[s.name] = (kind, {kv.key: kv.value for kv in s.values})
                    self.arrivals[s.name] = self.arrivals.get(s.name, 0) + 1

    def snapshot(self):
        """(the moving counters of every status, every queue empty, statuses received per name)."""
        with self.lock:
            moving = tuple(sorted((name, tuple(v.get(k) for k in MOVING[kind])) for name, (kind, v) in self.values.items()))
            empty = all(v.get(k) in ("0", None) for kind, v in self.values.values() for k in EMPTY[kind])
            odometry = [v for kind, v in self.values.values() if kind == "odometry"]
            busy = any(v.get("frames_processed") != v.get("frames_finished") for v in odometry)
            return moving, empty and not busy, dict(self.arrivals)

    def counts(self):
        """A line of what went through: the odometry's images and keyframes, the back-end's."""
        with self.lock:
            parts = []
            for name, (kind, v) in sorted(self.values.items(), key=lambda x: (x[1][0] != "odometry", x[0])):
                if kind == "odometry":
                    parts.append("%s images received, %s keyframes published" % (v.get("images_received"),
                                                                                  v.get("keyframes")))
                elif kind == "backend":
                    parts.append("the back-end took %s keyframes and %s loops, %s optimisations" % (
                        v.get("keyframes_received"), v.get("loops_received"), v.get("optimisations")))
            return "; ".join(parts) or "no diagnostics from the pipeline"


def wait_until_idle(pipeline, quiet_s, timeout_s):
    """True once the pipeline has been idle for quiet_s seconds (see the module's doc), False after timeout_s."""
    deadline = time.monotonic() + timeout_s
    last, since, at_since = None, None, {}
    while not rospy.is_shutdown() and time.monotonic() < deadline:
        moving, empty, arrivals = pipeline.snapshot()
        now = time.monotonic()
        if moving != last or not empty or not moving:
            last, since, at_since = moving, now, arrivals
        elif now - since >= quiet_s and all(arrivals.get(n, 0) - at_since.get(n, 0) >= 2 for n, _ in moving):
            return True
        time.sleep(POLL_S)
    return False


def player_running(master, player):
    """Whether the player answers: registered with the master and its node's API reachable (a node
    that has exited can stay registered, e.g. by a parameter subscription it did not undo)."""
    try:
        uri = master.lookupNode(player)
    except rosgraph.MasterError:  # not registered (yet, or any more)
        return False
    try:
        code, _, _ = xmlrpc.client.ServerProxy(uri).getPid(rospy.get_name())
        return code == 1
    except (OSError, xmlrpc.client.Error):  # its process is gone
        return False


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--player", required=True, help="the rosbag player's node name")
    parser.add_argument("--ns", required=True, help="the pipeline's namespace")
    parser.add_argument("--stay-up", action="store_true", help="keep running once the bags are played (rviz)")
    parser.add_argument("--quiet-s", type=float, default=3.0,
                        help="seconds the pipeline's counters must stay still to be idle (default 3)")
    parser.add_argument("--start-timeout", type=float, default=60.0,
                        help="seconds to wait for the player to register (default 60)")
    parser.add_argument("--drain-timeout", type=float, default=600.0,
                        help="seconds to wait for the pipeline to go idle after the bags (default 600)")
    args = parser.parse_args(rospy.myargv(sys.argv)[1:])
    rospy.init_node("replay_end")
    player = rosgraph.names.resolve_name(args.player, rospy.get_namespace())
    ns = rosgraph.names.resolve_name(args.ns, rospy.get_namespace())
    master = rosgraph.Master(rospy.get_name())
    pipeline = Pipeline(ns)
    start = time.monotonic()
    while not player_running(master, player):
        if rospy.is_shutdown():
            return 0
        if time.monotonic() - start > args.start_timeout:
            rospy.logerr("replay_end: the player %s did not start within %.0f s (its error is above): ending the "
                         "replay", player, args.start_timeout)
            return 1
        time.sleep(POLL_S)
    while player_running(master, player) and not rospy.is_shutdown():
        time.sleep(POLL_S)
    if rospy.is_shutdown():
        return 0
    played = time.monotonic()
    rospy.loginfo("replay_end: the bag(s) ended (%s finished): waiting for the pipeline to finish their frames, "
                  "keyframes and loops", player)
    idle = wait_until_idle(pipeline, args.quiet_s, args.drain_timeout)
    if idle and not args.stay_up:  # the loops left pending by optimise_every: optimised and published now
        service = ns.rstrip("/") + "/optimise"
        try:
            rospy.wait_for_service(service, timeout=5.0)
            due = rospy.ServiceProxy(service, Optimise)().maps
            if due > 0:
                idle = wait_until_idle(pipeline, args.quiet_s, args.drain_timeout)
        except (rospy.ROSException, rospy.ServiceException) as e:
            rospy.logwarn("replay_end: %s not called (%s): the back-end optimises what is pending as it unloads",
                          service, e)
    said = "the pipeline is idle (%.1f s after the bag(s) ended): %s" % (time.monotonic() - played, pipeline.counts())
    if not idle:
        said = "the pipeline is still busy %.0f s after the bag(s) ended (--drain-timeout): %s" % (
            args.drain_timeout, pipeline.counts())
    if args.stay_up:
        rospy.loginfo("replay_end: %s. Staying up (stay_up:=true): Ctrl-C ends the replay", said)
        rospy.spin()
        return 0
    (rospy.loginfo if idle else rospy.logwarn)("replay_end: %s. Ending the replay (stay_up:=true keeps it up)", said)
    return 0


if __name__ == "__main__":
    sys.exit(main())
