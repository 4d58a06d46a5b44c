#!/usr/bin/python3
"""Resumes a paused rosbag player once the odometry is connected to it (replay.launch).

rosbag play publishes as soon as its delay (-d) is over, whether or not the subscribers have
connected; a message sent before a subscriber's connection opens is lost for it, uncounted. On a
slow or loaded computer the nodelets may still be loading then, and the replay's first images
never reach the odometry. replay.launch therefore starts the player paused (--pause) and this node
resumes it (the player's pause_playback service) once the odometry's process (the nodelet manager,
or the standalone odometry node) is subscribed to the image topic the player plays (the topic, or
an image_transport sub-topic of it) and the player has an open connection to it on every played
topic that process subscribes to. The subscriptions of one process are made together, so the
condition must hold at two polls a quarter of a second apart. After --timeout seconds the player
is resumed anyway, with a warning (a replay never hangs on this).
"""
import argparse
import sys
import time
import xmlrpc.client

import rosgraph
import rospy
from std_srvs.srv import SetBool

POLL_S = 0.05
STABLE_S = 0.25


def ready(master, player, subscriber, image):
    """(True, topics) when `subscriber` takes the player's image topic and is connected on every
    topic of the player's it subscribes to; else (False, why)."""
    publishers, subscribers, _ = master.getSystemState()
    played = {t for t, nodes in publishers if player in nodes}
    taken = {t for t, nodes in subscribers if subscriber in nodes and t in played}
    if not any(t == image or t.startswith(image + "/") for t in played):
        return False, "%s plays no %s (nor a transport of it): is it the bag's image topic (image:=)?" % (player, image)
    if not any(t == image or t.startswith(image + "/") for t in taken):
        return False, "%s does not subscribe to %s (or a transport of it) yet" % (subscriber, image)
    code, _, info = xmlrpc.client.ServerProxy(master.lookupNode(player)).getBusInfo(rospy.get_name())
    if code != 1:
        return False, "no bus information from %s" % player
    # Each connection: [id, the peer's name, direction, transport, topic, connected, ...].
    open_to = {c[4] for c in info if c[1] == subscriber and c[2] == "o" and c[5]}
    missing = sorted(taken - open_to)
    if missing:
        return False, "%s not connected yet on %s" % (subscriber, ", ".join(missing))
    return True, sorted(taken)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--player", required=True, help="the rosbag player's node name (started with --pause)")
    parser.add_argument("--subscriber", required=True,
                        help="the node that runs the odometry: the nodelet manager, or the standalone odometry node")
    parser.add_argument("--image", required=True, help="the image topic the odometry subscribes to")
    parser.add_argument("--timeout", type=float, default=30.0,
                        help="seconds after which the player is resumed anyway (default 30)")
    args = parser.parse_args(rospy.myargv(sys.argv)[1:])
    rospy.init_node("resume_player")
    player = rosgraph.names.resolve_name(args.player, rospy.get_namespace())
    subscriber = rosgraph.names.resolve_name(args.subscriber, rospy.get_namespace())
    image = rosgraph.names.resolve_name(args.image, rospy.get_namespace())
    master = rosgraph.Master(rospy.get_name())
    start = time.monotonic()
    since, why = None, ""
    while not rospy.is_shutdown():
        try:
            ok, what = ready(master, player, subscriber, image)
        except (rosgraph.MasterException, OSError, xmlrpc.client.Fault) as e:  # e.g. the player not registered yet
            ok, what = False, str(e)
        now = time.monotonic()
        if not ok:
            since, why = None, what
        elif since is None:
            since = now
        elif now - since >= STABLE_S:
            rospy.loginfo("resume_player: %s is connected to %s on %s: playing (%.1f s after start)", subscriber,
                          player, ", ".join(what), now - start)
            break
        if now - start > args.timeout:
            rospy.logwarn("resume_player: after %.0f s %s: playing anyway (its first messages may be lost)",
                          args.timeout, why)
            break
        time.sleep(POLL_S)
    if rospy.is_shutdown():
        return
    service = player + "/pause_playback"
    try:
        rospy.wait_for_service(service, timeout=max(1.0, args.timeout - (time.monotonic() - start)))
        rospy.ServiceProxy(service, SetBool)(False)
    except (rospy.ROSException, rospy.ServiceException) as e:
        rospy.logerr("resume_player: %s failed: %s; the player stays paused (rosservice call %s false)", service, e,
                     service)
        sys.exit(1)


if __name__ == "__main__":
    main()
