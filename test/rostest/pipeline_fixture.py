"""Shared by the rostests: the small two-session mission they replay, the tool lookup, and the
waits for the pipeline's subscriptions."""
import math
import os
import signal
import subprocess
import tempfile
import threading
import time
import xmlrpc.client

import rosgraph
import roslib.packages
import rospy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Pose2D
from uw_multislam.msg import Keyframe

# Two overlapping loops (240 x 180 images); session 1's stamps start 1000 s after session 0's, so
# the odometry starts session 1 by its stamp gap rule when the bags are played one after another.
SURVEY = """
seed: 5
world: {width_m: 12, height_m: 10, metres_per_px: 0.008, featureless_fraction: 0.0}
sessions:
  - name: s0
    camera: {image_width: 240, image_height: 180, fx: 220, fy: 220, cx: 119.5, cy: 89.5}
    mission: {pattern: loop, start_m: [6.0, 5.0], length_m: 3.5, width_m: 2.5, laps: 1.3, speed_m_s: 0.35,
              frame_period_s: 1.0, altitude_m: 1.6, start_time_s: 0}
  - name: s1
    camera: {image_width: 240, image_height: 180, fx: 220, fy: 220, cx: 119.5, cy: 89.5}
    mission: {pattern: loop, start_m: [6.5, 5.5], heading_rad: 1.5708, length_m: 2.5, width_m: 3.0, laps: 1.0,
              speed_m_s: 0.35, frame_period_s: 1.0, altitude_m: 1.7, start_time_s: 1000}
"""
NS = os.environ.get("UWMS_TEST_NS", "/uw_multislam")  # the pipeline's namespace (a .test may move it)
SENSOR_TOPICS = ["/camera/image_raw", "/camera/camera_info", "/altitude"]


def backend_pid(caller):
    """The pid of this test's back-end, asked of the node through this test's master: a machine-wide
    pgrep for backend_node also finds the back-ends of other workspaces' tests and benchmarks running
    at the same time (and killed one of them)."""
    try:
        uri = rosgraph.Master(caller).lookupNode(NS + "/backend_node")
        code, _, pid = xmlrpc.client.ServerProxy(uri).getPid(caller)
    except (rosgraph.MasterError, OSError, xmlrpc.client.Error):
        return None
    return pid if code == 1 else None


def kill_backend_and_await_respawn(test, caller, timeout=60.0):
    """SIGKILL to this test's back-end, then waits (assertions of `test`) until roslaunch has
    respawned it under another pid."""
    pid = backend_pid(caller)
    test.assertIsNotNone(pid, "no back-end to kill")
    os.kill(pid, signal.SIGKILL)
    deadline = time.time() + timeout
    while time.time() < deadline and backend_pid(caller) in (None, pid):
        time.sleep(0.2)
    test.assertNotIn(backend_pid(caller), (None, pid), "the back-end was not respawned")


def tool(name):
    found = roslib.packages.find_node("uw_multislam", name)
    if not found:
        raise RuntimeError("uw_multislam/%s not built" % name)
    return found[0]


def wait_for_subscribers(topics, caller, timeout=60.0):
    """Until a node other than this test subscribes to each topic, then 2 s for the connections."""
    master = rosgraph.Master(caller)
    deadline = time.time() + timeout
    while time.time() < deadline:
        subscribed = {t: n for t, n in master.getSystemState()[1]}
        if all(any(n != rospy.get_name() for n in subscribed.get(t, [])) for t in topics):
            time.sleep(2.0)
            return
        time.sleep(0.5)
    raise AssertionError("the pipeline did not subscribe to %s within %.0f s" % (topics, timeout))


def connected(publishers, caller="/rostest_connections"):
    """True when each publisher has an open connection to every node the master lists as
    subscribed to its topic (and there is at least one). `get_num_connections() > 0` is not
    enough: this test node's own subscriber, or one of several pipeline nodes, may connect first;
    and rospy keeps counting a connection to a node that has gone until a publish finds it closed.
    A message published then is lost for the node that has not connected yet."""
    subscribed = {t: set(nodes) for t, nodes in rosgraph.Master(caller).getSystemState()[1]}
    for p in publishers:
        nodes = subscribed.get(p.resolved_name, set())
        open_to = {c.endpoint_id for c in list(p.impl.connections) if not c.done}
        if not nodes or not nodes <= open_to:
            return False
    return True


def synthetic_keyframe(session, k, features):
    """Keyframe k of a session driven straight along x, 0.5 m per keyframe (stamp 1000 + 100 *
    session + k s), with `features` random descriptors: for tests that feed the back-end directly."""
    m = Keyframe()
    m.header.stamp = rospy.Time(1000 + 100 * session + k)
    m.header.frame_id = "camera"
    m.session, m.keyframe, m.frame_index, m.altitude_m = session, k, k, 2.0
    m.width, m.height, m.fx, m.fy, m.cx, m.cy = 320, 240, 300.0, 300.0, 159.5, 119.5
    m.u_px = [float((7 * i) % 320) for i in range(features)]
    m.v_px = [float((13 * i) % 240) for i in range(features)]
    m.response = [float(features - i) for i in range(features)]
    m.descriptor_size = 128
    m.descriptors = os.urandom(128 * features)
    m.odometry_pose = Pose2D(0.5 * k, 0.0, 0.0)
    if k > 0:
        m.motion = Pose2D(0.5, 0.0, 0.0)
        m.motion_covariance = [1e-4, 0, 0, 0, 1e-4, 0, 0, 0, 1e-4]
        m.status, m.matches, m.inliers, m.overlap, m.scale = Keyframe.MATCHED, 200, 150, 0.8, 1.0
    else:
        m.status, m.scale = Keyframe.FIRST, 1.0
    return m


def wait_until_quiet(lock, last_message_time, quiet_s, timeout=120.0):
    """Until no message arrived for quiet_s seconds: last_message_time() is read under lock."""
    deadline = time.time() + timeout
    while time.time() < deadline:
        with lock:
            if time.time() - last_message_time() > quiet_s:
                return
        time.sleep(0.2)


def make_mission(prefix, survey=SURVEY, timeout=120):
    """A new temporary directory holding survey.yaml and the mission make_survey generates from it
    (dataset folders, bags, world_gt.csv): returns (the directory, the mission folder)."""
    tmp = tempfile.mkdtemp(prefix=prefix)
    with open(os.path.join(tmp, "survey.yaml"), "w") as f:
        f.write(survey)
    mission = os.path.join(tmp, "mission")
    subprocess.run([tool("make_survey"), "--config", os.path.join(tmp, "survey.yaml"), "--out", mission, "--quiet"],
                   check=True, timeout=timeout)
    return tmp, mission


def bag_frames(path, topics=SENSOR_TOPICS):
    """A bag's messages on `topics` (default the (image, camera_info, altitude) of SENSOR_TOPICS),
    grouped by header stamp, in stamp order; stamps that lack one of them are left out."""
    import rosbag
    by_stamp = {}
    with rosbag.Bag(path) as bag:
        for topic, msg, _ in bag.read_messages(topics=topics):
            by_stamp.setdefault(msg.header.stamp.to_nsec(), {})[topic] = msg
    return [tuple(f[t] for t in topics) for _, f in sorted(by_stamp.items()) if len(f) == len(topics)]


def stop_launch(launch, timeout=60):
    """Stops a roslaunch started with subprocess.Popen as Ctrl-C does (SIGINT), killed after
    `timeout` seconds."""
    if launch.poll() is None:
        launch.send_signal(signal.SIGINT)
        try:
            launch.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            launch.kill()
            launch.wait()


def frames_by_stamp(mission, names=("s0", "s1")):
    """{image stamp (ns): (session, index)} for the mission's bags, index as in world_gt.csv.
    A test matches what the pipeline publishes to the ground truth by the image's stamp, never by
    counting the images it or the pipeline received: a bag's first messages can be lost while
    rosbag play's connections open, on a loaded machine even after its -d delay."""
    out = {}
    for session, name in enumerate(names):
        for index, (image,) in enumerate(bag_frames(os.path.join(mission, name + ".bag"), SENSOR_TOPICS[:1])):
            out[image.header.stamp.to_nsec()] = (session, index)
    return out


def map_origin(keyframes, frames, most_lost=2):
    """(session, index) of map 0's origin: the image of session 0's keyframe 0 (the map frame is
    that keyframe's). It is image 0 unless the first images were lost in transport; more than
    `most_lost` of them is an error (the pipeline did not start on the first images it was sent)."""
    first = [k for k in keyframes if k.session == 0 and k.keyframe == 0]
    if not first:
        raise AssertionError("no keyframe 0 of session 0 received")
    origin = frames[first[0].header.stamp.to_nsec()]
    if origin[1] > most_lost:
        raise AssertionError("session 0 started at image %d of its bag" % origin[1])
    return origin


def diagnostic_values(status):
    """A diagnostic_msgs/DiagnosticStatus's key/value pairs, numbers as floats."""
    out = {}
    for kv in status.values:
        try:
            out[kv.key] = float(kv.value)
        except ValueError:
            out[kv.key] = kv.value
    return out


def appender(lock, store):
    """A subscriber callback that appends each message to `store` under `lock`."""
    def callback(msg):
        with lock:
            store.append(msg)
    return callback


def compose(a, b):
    """Planar poses (x, y, yaw): a (+) b."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], math.remainder(a[2] + b[2], 2 * math.pi)


def invert(a):
    c, s = math.cos(a[2]), math.sin(a[2])
    return -c * a[0] - s * a[1], s * a[0] - c * a[1], -a[2]


def mount_of_params(camera_frame="camera", timeout=30.0):
    """The camera's (x, y, yaw) in base_link, from tf (the launch's camera_mount, scripts/mount_publisher.py):
    the yaw of the image columns (the optical frame's x) in base_link's plane."""
    import tf2_ros
    buffer = tf2_ros.Buffer()
    listener = tf2_ros.TransformListener(buffer)  # noqa: F841 (fills the buffer)
    # Polled on wall time: with use_sim_time the clock may not run yet (a bag not playing).
    deadline = time.time() + timeout
    while not buffer.can_transform("base_link", camera_frame, rospy.Time(0)):
        if time.time() > deadline:
            raise AssertionError("no base_link -> %s in tf within %.0f s" % (camera_frame, timeout))
        time.sleep(0.05)
    t = buffer.lookup_transform("base_link", camera_frame, rospy.Time(0)).transform
    q = t.rotation
    # The optical x axis in base_link: the first column of the rotation matrix.
    x0, x1 = 1 - 2 * (q.y * q.y + q.z * q.z), 2 * (q.x * q.y + q.w * q.z)
    return t.translation.x, t.translation.y, math.atan2(x1, x0)


def vehicle_from_camera(p, mount=(0.0, 0.0, 0.0)):
    """base_link's pose in a z-up frame from a camera pose in the core's (image axes, z into the
    seabed; ground truth and offline_slam's files): (x, -y, -yaw) (+) (-)mount, as
    core::vehicleFromCamera (doc/frames.md)."""
    return compose((p[0], -p[1], -p[2]), invert(mount))


def matmul3(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def transpose3(a):
    return [list(r) for r in zip(*a)]


def chain_covariance(poses, covariances):
    """The last pose's covariance in the first one's frame, the motions between consecutive
    `poses` (x, y, yaw) with covariances[k] (3x3 lists, k >= 1) composed to first order, written
    out: x_k = x_{k-1} (+) m_k, P_k = J1 P J1' + J2 C_k J2'."""
    yaw = 0.0
    cov = [[0.0] * 3 for _ in range(3)]
    for k in range(1, len(poses)):
        a, b = poses[k - 1], poses[k]
        ca, sa = math.cos(a[2]), math.sin(a[2])
        mx, my = ca * (b[0] - a[0]) + sa * (b[1] - a[1]), -sa * (b[0] - a[0]) + ca * (b[1] - a[1])
        c, s = math.cos(yaw), math.sin(yaw)
        j1 = [[1, 0, -s * mx - c * my], [0, 1, c * mx - s * my], [0, 0, 1]]
        j2 = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
        p1, p2 = matmul3(matmul3(j1, cov), transpose3(j1)), matmul3(matmul3(j2, covariances[k]), transpose3(j2))
        cov = [[p1[i][j] + p2[i][j] for j in range(3)] for i in range(3)]
        yaw += math.atan2(math.sin(b[2] - a[2]), math.cos(b[2] - a[2]))
    return cov


def planar_covariance(msg_covariance):
    """The (x, y, yaw) block of a 6x6 row-major ROS covariance."""
    slots = (0, 1, 5)
    return [[msg_covariance[6 * slots[i] + slots[j]] for j in range(3)] for i in range(3)]


def await_condition(lock, condition, timeout, what, state=lambda: ""):
    """Until condition() (called under `lock`) holds, polling every 0.1 s for at most `timeout`
    seconds; then an AssertionError naming `what` and state() (also under the lock)."""
    deadline = time.time() + timeout
    while time.time() < deadline:
        with lock:
            if condition():
                return
        time.sleep(0.1)
    with lock:
        raise AssertionError("timed out after %.0f s waiting for %s%s" % (timeout, what, state()))


def messages_received(node, topic, caller="/rostest_bus_stats"):
    """How many messages `node` (a roscpp node's name) has taken from its publishers on `topic`,
    from its slave API's getBusStats: a message counted there has reached that node's subscription
    (its callback queue), which a test cannot see otherwise when the node publishes nothing about it."""
    uri = rosgraph.Master(caller).lookupNode(node)
    answer = xmlrpc.client.ServerProxy(uri).getBusStats(caller)
    # roscpp answers [publications, subscriptions] (its status code and message are overwritten: the
    # callback fills its result with the statistics), other clients [code, message, [publications,
    # subscriptions, services]]; a subscription is [topic, [[connection id, bytes, messages, drops, 0], ...]].
    stats = answer[2] if len(answer) == 3 and answer[0] == 1 else answer
    return sum(c[2] for t, conns in stats[1] if t == topic for c in conns)


def publisher_connected(node, topic, caller="/rostest_bus_info"):
    """True when `node` (another process publishing `topic`, e.g. a relay) has a connection to every
    node the master lists as subscribed to `topic` (and there is at least one): connected() for a
    publisher the test does not own. Its first message would be lost for a subscriber not connected yet."""
    master = rosgraph.Master(caller)
    subscribed = {t: set(nodes) for t, nodes in master.getSystemState()[1]}.get(topic, set())
    code, _, info = xmlrpc.client.ServerProxy(master.lookupNode(node)).getBusInfo(caller)
    if code != 1:
        raise AssertionError("getBusInfo of %s failed" % node)
    # Each connection: [id, the peer's name, direction, transport, topic, connected, ...].
    open_to = {c[1] for c in info if c[4] == topic and c[2] == "o" and c[5]}
    return bool(subscribed) and subscribed <= open_to


class DiagnosticsWatch:
    """The newest values (diagnostic_values: numbers as floats) of each /diagnostics status named
    "<node>: <name>" for a name in `names`, kept in `values` under `lock`: the caller's, so that
    await_condition can join them with its own messages (a new lock when None). `values` is keyed
    by the status's name ({"backend": {...}}), or with by_node by its node's own name
    ({"local_loops_node": {...}}: two nodes with a status of the same name); a key is absent until
    its first status. With `namespace` ("auv_a"), only nodes under /auv_a/. With `history`, also
    every status's values in order, in history ({key: [values, ...]}). The nodelets publish their
    status once a second; unregister() unsubscribes."""

    def __init__(self, names=("backend",), lock=None, namespace=None, by_node=False, history=False):
        self.names, self.namespace, self.by_node = set(names), namespace, by_node
        self.lock = lock if lock is not None else threading.Lock()
        self.values = {}
        self.history = {} if history else None
        self._changed = threading.Condition(self.lock)
        self._sub = rospy.Subscriber("/diagnostics", DiagnosticArray, self._on_diagnostics, queue_size=100)

    def _on_diagnostics(self, msg):
        with self._changed:
            for s in msg.status:
                node, _, name = s.name.rpartition(": ")
                if name in self.names and (self.namespace is None or
                                           node.lstrip("/").startswith(self.namespace + "/")):
                    key = node.split("/")[-1] if self.by_node else name
                    self.values[key] = diagnostic_values(s)
                    if self.history is not None:
                        self.history.setdefault(key, []).append(self.values[key])
            self._changed.notify_all()

    def get(self, key="backend"):
        """The newest values under `key` ({} before its first status). Each status's values are
        replaced, never changed in place: read with or without the lock (await_condition's
        conditions hold it)."""
        return self.values.get(key, {})

    def await_values(self, key="backend", condition=lambda v: True, timeout=20.0):
        """The first values under `key` for which condition(values) holds, or the newest seen when
        none did within `timeout` seconds (None when none came). With key None, condition and the
        answer are about all of `values` (a copy)."""
        def current():
            return dict(self.values) if key is None else self.values.get(key)

        deadline = time.time() + timeout
        with self._changed:
            while not (current() is not None and condition(current())):
                left = deadline - time.time()
                if left <= 0:
                    break
                self._changed.wait(min(left, 0.2))
            found = current()
            return dict(found) if found is not None else None

    def unregister(self):
        """As a rospy.Subscriber's: a watch can join a test's list of subscriptions."""
        self._sub.unregister()


def status_values(name="backend", condition=lambda v: True, timeout=20.0, namespace=None, node=None):
    """DiagnosticsWatch.await_values on a watch of its own, unregistered after: for a test that
    needs one status once, not a subscription kept through the test. With `node` ("odometry_node"),
    only that node's status `name`."""
    watch = DiagnosticsWatch((name,), namespace=namespace, by_node=node is not None)
    try:
        return watch.await_values(name if node is None else node, condition, timeout)
    finally:
        watch.unregister()


def backend_values(condition=lambda v: True, timeout=20.0):
    """The values of the first back-end status on /diagnostics (published every second) for which
    condition(values) holds, or of the last one seen when none did within `timeout` seconds."""
    return status_values("backend", condition, timeout)
