#!/usr/bin/python3
"""The live cases of the fault matrix (scripts/fault_matrix.py): each runs in a process of its own
(rospy talks to one master per process), with a ROS master of its own on a free port, slam.launch
with a session store in its temporary directory, and prints its rows as `ROW <json>` lines.

    fault_matrix_live.py CASE --survey DIR --dir DIR     (run by fault_matrix.py)
"""
import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import xmlrpc.client

from fault_matrix import SURVEY, integrity, keyframe_count, ro_connect, wait_for  # this script's folder is on sys.path

NS = "/uw_multislam"
REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TOPICS = ["/camera/image_raw", "/camera/camera_info", "/altitude"]


def rss_mb(pid):
    try:
        with open("/proc/%d/status" % pid) as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except (OSError, TypeError):
        pass
    return None


def fmt_mb(v):
    return "?" if v is None else "%.0f MB" % v


class Stack:
    """roscore on a free port and slam.launch, each in a process group of its own; stop() ends both."""

    def __init__(self, work):
        self.work = work
        self.store = os.path.join(work, "store", "s.db")
        s = socket.socket()
        s.bind(("127.0.0.1", 0))
        self.port = s.getsockname()[1]
        s.close()
        self.uri = "http://127.0.0.1:%d" % self.port
        os.environ.update(ROS_MASTER_URI=self.uri, ROS_HOSTNAME="127.0.0.1", ROS_HOME=os.path.join(work, "ros_home"),
                          ROS_LOG_DIR=os.path.join(work, "ros_home", "log"))
        self.procs = []
        self.core = self.spawn(["roscore", "-p", str(self.port)], "roscore.log")
        import rosgraph
        self.master = rosgraph.Master("/fault_matrix", master_uri=self.uri)
        if not wait_for(self.master_up, 30):
            raise RuntimeError("the ROS master on port %d did not come up" % self.port)
        self.launch = None

    def master_up(self):
        try:
            self.master.getPid()
            return True
        except Exception:
            return False

    def spawn(self, cmd, log):
        p = subprocess.Popen(cmd, stdout=open(os.path.join(self.work, log), "a"), stderr=subprocess.STDOUT,
                             start_new_session=True)
        self.procs.append(p)
        return p

    def start_slam(self, *args):
        self.launch = self.spawn(["roslaunch", "--wait", "uw_multislam", "slam.launch", "camera_mount:=0 0 0 0", "store_path:=" + self.store] +
                                 list(args), "launch.log")
        if not wait_for(lambda: self.launch.poll() is not None or self.services_ready(), 60, 0.2) or \
                self.launch.poll() is not None:
            raise RuntimeError("slam.launch: list_sessions did not answer OK within 60 s (launch.log: %s)" %
                               self.log_tail("launch.log"))

    def log_tail(self, name):
        with open(os.path.join(self.work, name), errors="replace") as f:
            return " / ".join(line.strip() for line in f.read().splitlines()[-2:])

    def services_ready(self):
        try:
            from uw_multislam.msg import Status
            return self.call("list_sessions", timeout=2).status.code == Status.OK
        except Exception:
            return False

    def call(self, name, *request, timeout=10.0):
        import rospy
        from uw_multislam import srv
        kinds = {"list_sessions": srv.ListSessions, "join_sessions": srv.JoinSessions, "split_session": srv.SplitSession,
                 "start_session": srv.StartSession, "reload_session": srv.ReloadSession, "export": srv.ExportSurvey,
                 "add_link": srv.AddLink, "keyframe_features": srv.KeyframeFeatures}
        rospy.wait_for_service(NS + "/" + name, timeout=timeout)
        return rospy.ServiceProxy(NS + "/" + name, kinds[name])(*request)

    def node_pid(self, node):
        try:
            import rosnode
            api = rosnode.get_api_uri(self.master, node, skip_cache=True)
            return xmlrpc.client.ServerProxy(api).getPid("/fault_matrix")[2] if api else None
        except Exception:
            return None

    def manager_pid(self):
        return self.node_pid(NS + "/manager")

    def alive(self):
        """Every node of the namespace answers a ping."""
        import rosnode
        nodes = [n for n in rosnode.get_node_names() if n.startswith(NS + "/")]
        dead = [n for n in nodes if not rosnode.rosnode_ping(n, max_count=1, verbose=False)]
        return nodes, dead

    def sessions(self):
        r = self.call("list_sessions")
        return [(s.session, s.name, s.state, s.map, s.num_keyframes) for s in r.sessions]

    def play(self, bag, rate=4.0, timeout=120):
        p = self.spawn(["rosbag", "play", "-q", "-r", str(rate), bag, "--topics"] + TOPICS, "play.log")
        p.wait(timeout=timeout)
        return p.returncode

    @staticmethod
    def stop_group(p, sig=signal.SIGINT):
        if p.poll() is not None:
            return
        for s, wait_s in ((sig, 15), (signal.SIGTERM, 5), (signal.SIGKILL, 5)):
            try:
                os.killpg(p.pid, s)
            except ProcessLookupError:
                return
            try:
                p.wait(timeout=wait_s)
                return
            except subprocess.TimeoutExpired:
                pass

    def stop(self):
        for p in reversed(self.procs):
            self.stop_group(p)


def row(case, expected, observed, held):
    print("ROW " + json.dumps([case, expected, observed, bool(held)]), flush=True)


def status_code(res):
    return res.status.code, res.status.message


# ---- cases -------------------------------------------------------------------------------------


def two_sessions(st, survey):
    """Two sessions from the survey's two bags (the second's stamps start again: a new session)."""
    st.play(os.path.join(survey, "a.bag"))
    wait_for(lambda: len(st.sessions()) >= 1 and st.sessions()[0][4] > 2, 30, 0.5)
    st.play(os.path.join(survey, "b.bag"))
    return wait_for(lambda: len(st.sessions()) >= 2 and st.sessions()[1][4] > 2, 30, 0.5)


def case_service_misuse(st, survey):
    # start_session is rate-limited to max_empty_sessions empty sessions (default 1): raised here so
    # that each of the names below reaches the name checks.
    with open(os.path.join(REPO, "config", "default.yaml")) as f:
        config = f.read()
    if "max_empty_sessions: 1\n" not in config:
        raise RuntimeError("config/default.yaml: max_empty_sessions: 1 not found")
    mine = os.path.join(st.work, "default.yaml")
    with open(mine, "w") as f:
        f.write(config.replace("max_empty_sessions: 1\n", "max_empty_sessions: 10\n"))
    st.start_slam("config:=" + mine)
    two_sessions(st, survey)
    pid = st.manager_pid()
    rss0 = rss_mb(pid)
    before = st.sessions()
    big = 2 ** 31 - 1
    calls = [
        ("join_sessions 0 0 (self-join)", "join_sessions", (0, 0, 0)),
        ("join_sessions 0 7 (unknown id)", "join_sessions", (0, 7, 0)),
        ("join_sessions -1 0 (negative id)", "join_sessions", (-1, 0, 0)),
        ("join_sessions 0 2^31-1 (huge id)", "join_sessions", (0, big, 0)),
        ("join_sessions 0 1 -5 (negative min_loops)", "join_sessions", (0, 1, -5)),
        ("split_session -1", "split_session", (-1,)),
        ("split_session 2^31-1", "split_session", (big,)),
        ("reload_session of an unknown name", "reload_session", ("no_such_session",)),
    ]
    # A split that succeeds, then the same split again; then the join back (both may fail for too few loops).
    names = [("quotes", "it's \"a\" name", "ok"), ("SQL", "x'); DROP TABLE sessions; --", "ok"),
             ("100 kB", "n" * 100000, "refused"), ("newline and tab", "a\nb\tc", "either")]
    bad = []
    for label, name, request in calls:
        code, msg = status_code(st.call(name, *request))
        if code == 0 or not msg:
            bad.append("%s: code %d '%s'" % (label, code, msg))
    after_misuse = st.sessions()
    # The one legitimate split (the two sessions joined by their global loops), then the same again.
    joined = len(before) > 1 and before[0][3] == before[1][3]
    split_note = "sessions 0 and 1 not joined: no double split"
    if joined:
        c1, m1 = status_code(st.call("split_session", 1))
        c2, m2 = status_code(st.call("split_session", 1))
        split_note = "split 1: code %d, again: code %d '%s'" % (c1, c2, m2[:60])
        if c1 != 0 or c2 == 0 or not m2:
            bad.append("double split: " + split_note)
        st.call("join_sessions", 0, 1, 0)
    else:
        bad.append(split_note)
    # Quotes and SQL metacharacters are a name like any other (kept verbatim, listed once); a
    # 100 kB name is a wrong call (refused with a message); control characters: either, reported.
    name_notes = []
    for label, name, must in names:
        code, msg = status_code(st.call("start_session", name))
        name_notes.append("%s: %s" % (label, "OK" if code == 0 else "code %d '%s'" % (code, msg[:50])))
        listed = [s for s in st.sessions() if s[1] == name]
        if must == "ok" and (code != 0 or len(listed) != 1):
            bad.append("start_session %s: code %d, listed %d times" % (label, code, len(listed)))
        if must == "refused" and (code == 0 or not msg):
            bad.append("start_session %s answered OK (a %d-byte name listed %d times)" % (label, len(name), len(listed)))
        if code != 0 and not msg:
            bad.append("start_session %s: code %d without a message" % (label, code))
    # Wrong argument counts through sessions.py: a usage error, non-zero, nothing called.
    for args in (["join", "0"], ["split"], ["join", "0", "1", "2", "3"], ["split", "x"]):
        r = subprocess.run(["/usr/bin/python3", os.path.join(REPO, "src", "tools", "sessions.py")] + args,
                           capture_output=True, text=True, timeout=60)
        if r.returncode == 0 or not r.stderr.strip():
            bad.append("sessions.py %s: status %d" % (" ".join(args), r.returncode))
    nodes, dead = st.alive()
    state_same = after_misuse == before
    rss1 = rss_mb(pid)
    st.stop_group(st.launch)
    ok = integrity(st.store)
    held = not bad and not dead and nodes and state_same and ok == "ok"
    observed = ("%d wrong calls each answered non-OK with a message%s; list_sessions %s; %s; start_session names %s; "
                "%d nodes alive%s; integrity %s; manager RSS %s -> %s") % (
        len(calls) + 4, "" if not bad else " EXCEPT " + "; ".join(bad), "unchanged" if state_same else "CHANGED",
        split_note, ", ".join(name_notes), len(nodes), "" if not dead else ", DEAD: %s" % dead, ok, fmt_mb(rss0),
        fmt_mb(rss1))
    row("live: service misuse (ids, double split, names, argument counts)",
        "each wrong call non-OK with a message (a 100 kB name too); quoted/SQL names kept verbatim; nodes up; "
        "list_sessions unchanged by wrong calls; integrity ok", observed, held)


def case_concurrent(st, survey, seconds=12.0, threads=20, deadline_s=10.0):
    st.start_slam()
    two_sessions(st, survey)
    pid = st.manager_pid()
    rss0 = rss_mb(pid)
    import rospy
    from uw_multislam import srv
    rospy.wait_for_service(NS + "/join_sessions", timeout=10)
    # A rospy "transport error" (the socket closed before the answer came) was seen once in 5047
    # calls on a loaded CI machine while the manager stayed up and answered everything else; the
    # server-side cause is not known. Such a call is retried once and counted: the case still fails
    # when the retry fails, when they are more than 1 in 1000 calls, or on any error the manager
    # answered (a non-OK status is an answer, not an error, here).
    stats = {"calls": 0, "slowest": 0.0, "errors": [], "transport_retries": 0}
    lock = threading.Lock()
    stop_at = time.monotonic() + seconds

    def worker(i):
        join = rospy.ServiceProxy(NS + "/join_sessions", srv.JoinSessions, persistent=False)
        split = rospy.ServiceProxy(NS + "/split_session", srv.SplitSession, persistent=False)
        n = 0
        while time.monotonic() < stop_at:
            t0 = time.monotonic()
            for attempt in range(2):
                try:
                    if (i + n) % 2:
                        join(0, 1, 0)
                    else:
                        split(1)
                    break
                except Exception as e:
                    transport = "transport error" in str(e)
                    with lock:
                        if transport and attempt == 0:
                            stats["transport_retries"] += 1
                            continue
                        stats["errors"].append(repr(e)[:80])
                    break
            dt = time.monotonic() - t0
            n += 1
            with lock:
                stats["calls"] += 1
                stats["slowest"] = max(stats["slowest"], dt)

    pool = [threading.Thread(target=worker, args=(i,), daemon=True) for i in range(threads)]
    for t in pool:
        t.start()
    for t in pool:
        t.join(timeout=seconds + deadline_s + 5)
    hung = sum(1 for t in pool if t.is_alive())
    nodes, dead = st.alive()
    listed = st.sessions()
    rss1 = rss_mb(pid)
    st.stop_group(st.launch)
    ok = integrity(st.store)
    held = (not hung and not stats["errors"] and stats["slowest"] < deadline_s and not dead and nodes and ok == "ok"
            and len(listed) >= 2 and stats["transport_retries"] * 1000 <= stats["calls"])
    observed = "%d calls in %.0f s by %d threads, slowest %.2f s, %d errors%s, %d transport errors retried, " \
               "%d threads hung; %d nodes alive%s; integrity %s; manager RSS %s -> %s" % (
                   stats["calls"], seconds, threads, stats["slowest"], len(stats["errors"]),
                   (" (%s)" % stats["errors"][0]) if stats["errors"] else "", stats["transport_retries"], hung, len(nodes),
                   "" if not dead else ", DEAD: %s" % dead, ok, fmt_mb(rss0), fmt_mb(rss1))
    row("live: %d concurrent join/split callers for %.0f s" % (threads, seconds),
        "every call answered within %.0f s (a transport error retried once, at most 1 in 1000 calls); nodes alive; "
        "integrity ok" % deadline_s, observed, held)


def case_kill_manager(st, survey):
    st.start_slam("standalone:=false")
    import rospy
    from uw_multislam.msg import Keyframe
    published = []
    rospy.init_node("fault_matrix", anonymous=True, disable_signals=True)
    rospy.Subscriber(NS + "/keyframes", Keyframe, lambda m: published.append(m), queue_size=1000)
    pid = st.manager_pid()
    rss0 = rss_mb(pid)
    player = st.spawn(["rosbag", "play", "-q", "-r", "2", os.path.join(survey, "a.bag"), "--topics"] + TOPICS,
                      "play.log")
    wait_for(lambda: len(published) >= 6, 60, 0.05)
    n_published = len(published)
    rss1 = rss_mb(pid)
    os.kill(pid, signal.SIGKILL)
    st.stop_group(player)
    st.stop_group(st.launch)
    stored = keyframe_count(st.store)
    ok = integrity(st.store)
    st.start_slam("standalone:=false")
    listed = st.sessions()
    held = (n_published >= 6 and ok == "ok" and stored is not None and stored >= n_published - 1 and len(listed) >= 1
            and listed[0][4] >= n_published - 1)
    observed = ("killed after %d keyframes published; store: %s keyframes, integrity %s; relaunched: list_sessions %s; "
                "manager RSS %s -> %s before the kill") % (n_published, stored, ok,
                                                          [(s[0], s[4]) for s in listed], fmt_mb(rss0), fmt_mb(rss1))
    row("live: kill -9 of the nodelet manager during a replay, relaunch on the store",
        "sessions listed again; stored keyframes >= published - 1; integrity ok", observed, held)


def case_kill_manager_moments(st, survey):
    """kill -9 of the nodelet manager at two more moments, each followed by a relaunch on the store:
    right after split_session answered OK (the split must survive), and during start-up, as soon as
    the manager process exists (before or while it loads the store)."""
    st.start_slam("standalone:=false")
    two_sessions(st, survey)
    before = st.sessions()
    joined = len(before) >= 2 and before[0][3] == before[1][3]
    pid = st.manager_pid()
    code, msg = status_code(st.call("split_session", 1))
    os.kill(pid, signal.SIGKILL)
    st.stop_group(st.launch)
    ok = integrity(st.store)
    st.start_slam("standalone:=false")
    after = st.sessions()
    expected = [(s[0], s[4]) for s in before]
    held = (joined and code == 0 and ok == "ok" and [(s[0], s[4]) for s in after] == expected and len(after) >= 2
            and after[0][3] != after[1][3])
    row("live: kill -9 of the nodelet manager right after split_session answered OK, relaunch",
        "the split kept (sessions 0 and 1 in different maps); the same sessions and keyframes; integrity ok",
        "before: %s (joined: %s); split_session 1: code %d%s; killed; integrity %s; relaunched: %s" % (
            [(s[0], s[3], s[4]) for s in before], joined, code, (" '%s'" % msg[:60]) if code else "", ok,
            [(s[0], s[3], s[4]) for s in after]), held)
    # During start-up: SIGINT the launch, start it again without waiting, kill -9 the manager as
    # soon as it is registered, then relaunch and list.
    st.stop_group(st.launch)
    st.launch = st.spawn(["roslaunch", "--wait", "uw_multislam", "slam.launch", "camera_mount:=0 0 0 0", "store_path:=" + st.store,
                          "standalone:=false"], "launch.log")
    pid = [None]
    wait_for(lambda: pid.__setitem__(0, st.manager_pid()) or pid[0], 60, 0.02)
    answered = st.services_ready()
    if pid[0]:
        os.kill(pid[0], signal.SIGKILL)
    st.stop_group(st.launch)
    ok = integrity(st.store)
    st.start_slam("standalone:=false")
    again = st.sessions()
    nodes, dead = st.alive()
    st.stop_group(st.launch)
    ok2 = integrity(st.store)
    held = (pid[0] is not None and ok == "ok" and ok2 == "ok" and again == after and nodes and not dead)
    row("live: kill -9 of the nodelet manager during start-up (store loading), relaunch",
        "the same sessions, maps and keyframes listed after the relaunch; integrity ok; nodes alive",
        "manager pid %s killed %s list_sessions answered; integrity %s; relaunched: %s (%s); %d nodes alive%s; "
        "integrity after %s" % (pid[0], "after" if answered else "before", ok, [(s[0], s[3], s[4]) for s in again],
                                "unchanged" if again == after else "CHANGED from %s" % [(s[0], s[3], s[4]) for s in after],
                                len(nodes), "" if not dead else ", DEAD: %s" % dead, ok2), held)


def case_bad_images(st, survey):
    st.start_slam("standalone:=false")
    import rosbag
    import rospy
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import Image
    rospy.init_node("fault_matrix", anonymous=True, disable_signals=True)
    latest = {}
    diag_count = [0]

    def on_diag(msg):
        diag_count[0] += 1
        for s in msg.status:
            if "odometry" in s.name:
                latest.update({kv.key: kv.value for kv in s.values})

    rospy.Subscriber("/diagnostics", DiagnosticArray, on_diag, queue_size=50)
    pubs = [rospy.Publisher(TOPICS[0], Image, queue_size=50)]
    from sensor_msgs.msg import CameraInfo, Range
    pubs += [rospy.Publisher(TOPICS[1], CameraInfo, queue_size=50), rospy.Publisher(TOPICS[2], Range, queue_size=50)]
    frames = {}
    with rosbag.Bag(os.path.join(survey, "a.bag")) as bag:
        for topic, msg, _ in bag.read_messages(topics=TOPICS):
            frames.setdefault(msg.header.stamp.to_nsec(), {})[topic] = msg
    frames = [f for _, f in sorted(frames.items()) if len(f) == 3]
    wait_for(lambda: all(p.get_num_connections() > 0 for p in pubs) and latest, 30, 0.1)
    pid = st.manager_pid()
    rss0 = rss_mb(pid)
    t = [frames[0][TOPICS[0]].header.stamp.to_sec()]
    sent, received0 = [0], int(float(latest.get("images_received", 0)))

    def handled(status):
        """Every image sent was received and nothing waits: not for pairing, in the queue or in the worker."""
        def n(key):
            return int(float(status.get(key, 0)))
        return (n("images_received") >= received0 + sent[0] and n("images_waiting_pairing") == 0 and
                n("queue_length") == 0 and n("frames_processed") == n("frames_finished"))

    def send(image, info, rng):
        t[0] += 1.0
        stamp = rospy.Time.from_sec(t[0])
        for msg in (image, info, rng):
            msg.header.stamp = stamp
        seen = diag_count[0]
        pubs[1].publish(info)
        pubs[2].publish(rng)
        pubs[0].publish(image)
        sent[0] += 1
        # Each frame handled before the next is sent: the odometry's newest-only rule passes over a
        # frame that waits while a slow one (the 100 MB image on a loaded machine) is processed,
        # and a frame passed over is counted as that, not by what is wrong with it.
        wait_for(lambda: diag_count[0] >= seen + 2 and handled(latest), 60, 0.05)

    def image(encoding, w, h, bpp):
        # The good frames' camera frame: a converted image (16UC1) reaches the mount lookup.
        im = Image(height=h, width=w, encoding=encoding, step=w * bpp)
        im.header.frame_id = frames[0][TOPICS[0]].header.frame_id
        im.data = bytes(w * h * bpp)
        return im

    import copy
    base_img, base_info, base_rng = frames[0][TOPICS[0]], frames[0][TOPICS[1]], frames[0][TOPICS[2]]
    # A few good frames first: the session starts and the altitude has a valid value to reuse.
    for f in frames[:3]:
        send(copy.deepcopy(f[TOPICS[0]]), copy.deepcopy(f[TOPICS[1]]), copy.deepcopy(f[TOPICS[2]]))
    start = dict(latest)
    w, h = base_info.width, base_info.height
    bad = [("16UC1", image("16UC1", w, h, 2), base_info), ("32FC1", image("32FC1", w, h, 4), base_info),
           ("yuv422", image("yuv422", w, h, 2), base_info)]
    tiny_info = copy.deepcopy(base_info)
    tiny_info.width, tiny_info.height = 1, 1
    bad.append(("1x1", image("mono8", 1, 1, 1), tiny_info))
    huge_info = copy.deepcopy(base_info)
    huge_info.width, huge_info.height = 10000, 10000
    bad.append(("10000x10000", image("mono8", 10000, 10000, 1), huge_info))
    for _, im, info in bad:
        send(im, copy.deepcopy(info), copy.deepcopy(base_rng))
    for value in (float("nan"), float("inf"), -2.0):
        rng = copy.deepcopy(base_rng)
        rng.range = value
        send(copy.deepcopy(base_img), copy.deepcopy(base_info), rng)
    def delta(end, key):
        try:
            return int(float(end.get(key, 0))) - int(float(start.get(key, 0)))
        except ValueError:
            return 0

    def counted(end):
        return {k: delta(end, k) for k in sorted(set(start) | set(end)) if delta(end, k) and k.startswith(("skipped", "bad_"))}

    def expected(counts):
        tiny = sum(counts.get(k, 0) for k in ("skipped_tiny_image", "skipped_size_mismatch", "skipped_camera_info"))
        # doc/robustness.md "Bad input": 16UC1 is scaled to 8 bits (processed), float and YUV are skipped_encoding.
        return (counts.get("skipped_encoding", 0) == 2 and tiny >= 1 and counts.get("skipped_image_too_large", 0) == 1
                and counts.get("bad_altitude_replaced", 0) == 3)

    # The counters from statuses published after the last frame (one a diagnostic_period): at least
    # three more, and until the expected counts show (a loaded machine takes seconds over the
    # 100 MB image: a CI run once read them 3 s after the last frame, before the last four were
    # counted), at most 60 s.
    seen = diag_count[0]
    wait_for(lambda: diag_count[0] >= seen + 3 and expected(counted(dict(latest))), 60, 0.1)
    end = dict(latest)
    counts = counted(end)
    nodes, dead = st.alive()
    rss1 = rss_mb(pid)
    held = expected(counts) and nodes and not dead
    observed = "counters changed: %s; %d nodes alive%s; manager RSS %s -> %s" % (
        ", ".join("%s +%d" % kv for kv in counts.items()) or "none", len(nodes), "" if not dead else ", DEAD: %s" % dead,
        fmt_mb(rss0), fmt_mb(rss1))
    row("live: images 16UC1, 32FC1, yuv422, 1x1, 10000x10000; altitudes NaN, inf, -2",
        "README Bad input: 16UC1 converted; skipped_encoding +2 (32FC1, yuv422); 1x1 skipped (tiny, size or "
        "camera_info) +1; skipped_image_too_large +1; bad_altitude_replaced +3; nodes alive",
        observed, held)


class NodeStatus:
    """A node's latest /diagnostics values (the odometry's unless another status name suffix is
    given; published every diagnostic period) and how many arrived."""

    def __init__(self, suffix=": odometry"):
        import rospy
        from diagnostic_msgs.msg import DiagnosticArray
        self.suffix = suffix
        self.latest, self.count = {}, 0
        self.sub = rospy.Subscriber("/diagnostics", DiagnosticArray, self.on_diag, queue_size=50)

    def on_diag(self, msg):
        for s in msg.status:
            if s.name.endswith(self.suffix):
                self.latest = {kv.key: kv.value for kv in s.values}
                self.count += 1

    def value(self, key):
        try:
            return int(float(self.latest.get(key, 0)))
        except ValueError:
            return 0

    def fresh(self, timeout=15):
        """Until two more statuses arrived (the second computed after what came before this call)."""
        seen = self.count
        return wait_for(lambda: self.count >= seen + 2, timeout, 0.1)


def bag_frames(survey, name):
    """The bag's (image, camera_info, altitude) triples in stamp order."""
    import rosbag
    frames = {}
    with rosbag.Bag(os.path.join(survey, name)) as bag:
        for topic, msg, _ in bag.read_messages(topics=TOPICS):
            frames.setdefault(msg.header.stamp.to_nsec(), {})[topic] = msg
    return [(f[TOPICS[0]], f[TOPICS[1]], f[TOPICS[2]]) for _, f in sorted(frames.items()) if len(f) == 3]


def sensor_publishers():
    import rospy
    from sensor_msgs.msg import CameraInfo, Image, Range
    pubs = [rospy.Publisher(TOPICS[0], Image, queue_size=2000), rospy.Publisher(TOPICS[1], CameraInfo, queue_size=2000),
            rospy.Publisher(TOPICS[2], Range, queue_size=2000)]
    wait_for(lambda: all(p.get_num_connections() > 0 for p in pubs), 30, 0.1)
    return pubs


def publishing_frames(st, survey, *launch_args):
    """slam.launch (nodelets in one manager) for a case that publishes bag a's frames itself: this
    process's node, the odometry's status, the sensor publishers (connected), the frames, the
    manager's pid and RSS, and the odometry's counters before anything is sent."""
    st.start_slam("standalone:=false", *launch_args)
    import rospy
    rospy.init_node("fault_matrix", anonymous=True, disable_signals=True)
    odo = NodeStatus()
    pubs = sensor_publishers()
    wait_for(lambda: odo.latest, 30, 0.1)
    frames = bag_frames(survey, "a.bag")
    pid = st.manager_pid()
    rss0 = rss_mb(pid)
    odo.fresh()
    return odo, pubs, frames, pid, rss0, dict(odo.latest)


def stored_as_published(st, odo, timeout=60):
    """Until the back-end lists as many keyframes as the odometry says it published (both polled)."""
    def same():
        return odo.latest and sum(s[4] for s in st.sessions()) == odo.value("keyframes")
    wait_for(same, timeout, 0.5)
    return sum(s[4] for s in st.sessions()), odo.value("keyframes")


def case_replay_rates(st, survey):
    """The survey's bag a replayed at rate 10, then again at rate 20 (its stamps start again: a new
    session by the stamp rule). Each: every keyframe the odometry published stored, no session from
    the node's own drops (time_jumps_forward 0), drops counted."""
    st.start_slam("standalone:=false")
    import rospy
    rospy.init_node("fault_matrix", anonymous=True, disable_signals=True)
    odo = NodeStatus()
    wait_for(lambda: odo.latest, 30, 0.1)
    pid = st.manager_pid()
    for rate in (10, 20):
        rss0 = rss_mb(pid)
        odo.fresh()
        before = dict(odo.latest)
        t0 = time.monotonic()
        status = st.play(os.path.join(survey, "a.bag"), rate=rate)
        played_s = time.monotonic() - t0
        stored, published = stored_as_published(st, odo)
        odo.fresh()
        delta = {k: odo.value(k) - int(float(before.get(k, 0))) for k in
                 ("images_received", "frames_processed", "dropped_queue_full", "images_not_paired", "time_jumps_forward",
                  "tracking_losses", "keyframes")}
        nodes, dead = st.alive()
        rss1 = rss_mb(pid)
        held = (status == 0 and stored == published and delta["keyframes"] > 0 and delta["time_jumps_forward"] == 0
                and nodes and not dead)
        observed = ("played in %.1f s (status %s); odometry: %s; back-end lists %d keyframes, the odometry published %d; "
                    "%d nodes alive%s; manager RSS %s -> %s") % (
            played_s, status, ", ".join("%s +%d" % kv for kv in delta.items()), stored, published, len(nodes),
            "" if not dead else ", DEAD: %s" % dead, fmt_mb(rss0), fmt_mb(rss1))
        row("live: replay at rate %d" % rate,
            "every published keyframe stored; drops counted; no session from drops (time_jumps_forward +0); nodes alive",
            observed, held)
    st.stop_group(st.launch)
    ok = integrity(st.store)
    row("live: the store after the replays at rate 10 and 20", "integrity ok", "integrity %s" % ok, ok == "ok")


def case_silent_altitude(st, survey, silent=range(6, 14)):
    """The survey's bag a published frame by frame (5 per second, stamps 1 s apart as recorded),
    the altitude topic silent for frames 6-13 (8 s of stamps, beyond altitude_max_age_s)."""
    import copy
    odo, pubs, frames, pid, rss0, before = publishing_frames(st, survey)
    for k, (image, info, rng) in enumerate(frames):
        image, info, rng = copy.deepcopy(image), copy.deepcopy(info), copy.deepcopy(rng)
        pubs[1].publish(info)
        if k not in silent:
            pubs[2].publish(rng)
        pubs[0].publish(image)
        time.sleep(0.2)  # publishing pace (5 Hz), not a wait for a condition
    stored, published = stored_as_published(st, odo)
    odo.fresh()
    delta = {k: odo.value(k) - int(float(before.get(k, 0))) for k in
             ("images_received", "skipped_no_altitude", "images_not_paired", "frames_processed", "time_jumps_forward",
              "tracking_losses", "keyframes")}
    nodes, dead = st.alive()
    rss1 = rss_mb(pid)
    st.stop_group(st.launch)
    ok = integrity(st.store)
    held = (delta["skipped_no_altitude"] >= 1 and delta["time_jumps_forward"] == 0 and stored == published
            and delta["keyframes"] > 0 and nodes and not dead and ok == "ok")
    observed = ("%d frames, %d without altitude; odometry: %s; back-end lists %d keyframes, the odometry published %d; "
                "%d nodes alive%s; integrity %s; manager RSS %s -> %s") % (
        len(frames), len([k for k in silent if k < len(frames)]), ", ".join("%s +%d" % kv for kv in delta.items()),
        stored, published, len(nodes), "" if not dead else ", DEAD: %s" % dead, ok, fmt_mb(rss0), fmt_mb(rss1))
    row("live: the altitude topic silent for %d frames (%d s of stamps)" % (len(silent), len(silent)),
        "images beyond altitude_max_age_s skipped and counted (skipped_no_altitude); no session from the gap "
        "(time_jumps_forward +0); every published keyframe stored; nodes alive; integrity ok", observed, held)


def case_burst(st, survey, n=1000):
    """1000 images (with camera_info and altitude) published at once, stamps 1 s apart (the bag's
    frames over and over: out and back, so its end is near its start).

    The odometry subscribes with sync_queue_size 1000 here (default 10): roscpp's subscriber queue
    drops the oldest messages without telling the node, and a run of more than session_gap_s of
    them is a gap in the stamps the node cannot tell from an outage (a CI run with the default lost
    117 of the 1000 images there and started 3 sessions). What the case holds the node to is its
    own drops: its frame queue (queue_size 5) and its pairing must never start a session."""
    import copy
    import rospy
    odo, pubs, frames, pid, rss0, before = publishing_frames(
        st, survey, "config:=" + config_with(st, "burst.yaml", {"odometry_node": {"sync_queue_size": n}}))
    t = frames[0][0].header.stamp.to_sec()
    t0 = time.monotonic()
    for k in range(n):
        image, info, rng = (copy.copy(m) for m in frames[k % len(frames)])
        stamp = rospy.Time.from_sec(t + k)
        for m in (image, info, rng):
            m.header = copy.deepcopy(m.header)
            m.header.stamp = stamp
        pubs[1].publish(info)
        pubs[2].publish(rng)
        pubs[0].publish(image)
    sent_s = time.monotonic() - t0
    # Until the odometry has received or refused every image and the back-end holds its keyframes.
    wait_for(lambda: odo.fresh(5) and odo.value("queue_length") == 0 and odo.value("images_waiting_pairing") == 0,
             90, 0.1)
    stored, published = stored_as_published(st, odo)
    odo.fresh()
    delta = {k: odo.value(k) - int(float(before.get(k, 0))) for k in
             ("images_received", "frames_processed", "dropped_queue_full", "images_not_paired", "skipped_no_altitude",
              "skipped_no_camera_info", "time_jumps_forward", "tracking_losses", "keyframes")}
    nodes, dead = st.alive()
    rss1 = rss_mb(pid)
    st.stop_group(st.launch)
    ok = integrity(st.store)
    held = (delta["images_received"] == n and delta["time_jumps_forward"] == 0 and stored == published
            and delta["keyframes"] > 0 and nodes and not dead and ok == "ok")
    observed = ("%d images sent in %.1f s; odometry: %s; back-end lists %d keyframes, the odometry published %d; "
                "%d nodes alive%s; integrity %s; manager RSS %s -> %s") % (
        n, sent_s, ", ".join("%s +%d" % kv for kv in delta.items()), stored, published, len(nodes),
        "" if not dead else ", DEAD: %s" % dead, ok, fmt_mb(rss0), fmt_mb(rss1))
    row("live: a burst of %d images (subscriber queue %d)" % (n, n),
        "every image received; the node's drops counted (queue, pairing); no session from them (time_jumps_forward +0); every published keyframe "
        "stored; nodes alive; integrity ok", observed, held)


# The matrix's session a alone, with the vehicle's dead reckoning on /nav/odom in its bag.
NAV_SURVEY = SURVEY[:SURVEY.index("  - name: b")] + "    nav: {enabled: true}\n"


def case_nav_clock_and_mount(st, survey):
    """A bag with its nav (/nav/odom) played, then a second mount publisher moves the camera 0.1 m
    and the bag is played again without its nav: its stamps jump back (a new session), and the nav
    readings of the clock before must be dropped, not found again at the same stamps; the moved
    mount is said (WARN), counted (mount_changes) and starts no session of its own."""
    import rospy
    import tf2_ros
    from rosgraph_msgs.msg import Log
    d = os.path.join(st.work, "nav_survey")
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, "survey.yaml"), "w") as f:
        f.write(NAV_SURVEY)
    r = subprocess.run([os.path.join(os.environ.get("UWMS_BIN_DIR", ""), "make_survey"), "--config",
                        os.path.join(d, "survey.yaml"), "--out", os.path.join(d, "m"), "--quiet"],
                       capture_output=True, text=True, timeout=120)
    if r.returncode != 0:
        row("live: nav and mount", "make_survey runs", "make_survey failed: " + r.stderr[-300:], False)
        return
    bag = os.path.join(d, "m", "a.bag")
    st.start_slam("standalone:=false")
    rospy.init_node("fault_matrix", anonymous=True, disable_signals=True)
    warnings, lock = [], threading.Lock()

    def on_log(m):
        if m.level == Log.WARN:  # the nodelets log as their manager
            with lock:
                warnings.append(m.msg)
    rospy.Subscriber("/rosout", Log, on_log, queue_size=1000)
    odo = NodeStatus()
    wait_for(lambda: odo.latest, 30, 0.1)
    n = len(bag_frames(os.path.join(d, "m"), "a.bag"))

    def play(topics):
        odo.fresh()
        before = dict(odo.latest)
        p = st.spawn(["rosbag", "play", "-q", "--wait-for-subscribers", "-r", "4", bag, "--topics"] + topics, "play.log")
        status = p.wait(timeout=120)
        # Until the odometry has received every image and is idle.
        wait_for(lambda: odo.fresh(5) and odo.value("queue_length") == 0 and
                 odo.value("images_received") - int(float(before.get("images_received", 0))) >= n, 60, 0.1)
        odo.fresh()
        return status, {k: odo.value(k) - int(float(before.get(k, 0))) for k in
                        ("images_received", "frames_processed", "frames_with_nav", "time_jumps_back", "sessions",
                         "mount_changes", "tracking_losses")}

    status1, first = play(TOPICS + ["/nav/odom"])
    # The second mount publisher, awaited in tf before the replay.
    st.spawn(["rosrun", "uw_multislam", "mount_publisher.py", "--camera", "camera", "0.1", "0", "0", "0",
              "__name:=second_mount_publisher"], "mount.log")
    buf = tf2_ros.Buffer()
    tf2_ros.TransformListener(buf)

    def moved():
        try:
            return abs(buf.lookup_transform("base_link", "camera", rospy.Time(0)).transform.translation.x - 0.1) < 1e-9
        except Exception:
            return False
    mount_seen = wait_for(moved, 30, 0.1)
    status2, second = play(TOPICS)
    wait_for(lambda: odo.fresh(5) and odo.value("mount_changes") >= 1, 15, 0.1)
    with lock:
        dropped = [w for w in warnings if "nav readings of the clock before dropped" in w]
        said = [w for w in warnings if "mount moved in tf" in w]
    nodes, dead = st.alive()
    st.stop_group(st.launch)
    ok = integrity(st.store)
    held = (status1 == 0 and first["frames_with_nav"] > 0 and status2 == 0 and second["time_jumps_back"] == 1 and
            second["frames_processed"] > 0 and second["frames_with_nav"] == 0 and len(dropped) == 1)
    row("live: the image clock jumps back (the bag with its nav played, then again without it)",
        "a new session (time_jumps_back +1); the nav readings of the old clock dropped (one WARN): no frame of the "
        "replay given a nav pose (frames_with_nav +0)",
        "first play (status %s): %s; replay (status %s): %s; %d WARN of dropped readings%s" % (
            status1, first, status2, second, len(dropped), ": " + dropped[0] if dropped else ""), held)
    held = (mount_seen and odo.value("mount_changes") == 1 and second["sessions"] == 1 and len(said) == 1 and
            nodes and not dead and ok == "ok")
    row("live: a second mount publisher moves the camera 0.1 m between the two plays",
        "said once (WARN naming both mounts), counted (mount_changes 1) and used; no session from it (sessions +1 "
        "in the replay: its jump back only); nodes alive; integrity ok",
        "moved mount in tf: %s; mount_changes %d; sessions +%d in the replay; %d WARN%s; %d nodes alive%s; "
        "integrity %s" % (mount_seen, odo.value("mount_changes"), second["sessions"], len(said),
                          ": " + said[0] if said else "", len(nodes), "" if not dead else ", DEAD: %s" % dead, ok),
        held)


def config_with(st, name, overrides):
    """The launch's config (config/default.yaml) with {node: {key: value}} changed, written into the
    case's folder (slam.launch loads its config file over any parameter set before the launch)."""
    import yaml
    with open(os.path.join(REPO, "config", "default.yaml")) as f:
        config = yaml.safe_load(f)
    for node, values in overrides.items():
        config[node].update(values)
    path = os.path.join(st.work, name)
    with open(path, "w") as f:
        yaml.safe_dump(config, f)
    return path


def case_store_cap(st, survey, room_kb=64):
    """A full disk through ROS. A first run (its own store) measures the file after bag
    a; the second, on a new store, is launched with store_max_mb that size plus 64 kB (room for small
    writes, not for bag b's keyframes), plays bags a and b, then split_session 1 and join_sessions 0 1.
    The back-end must count the failed writes on /diagnostics (store_failures), go on in memory
    (keyframes listed, split and join answered OK), and leave a store that passes integrity_check and
    restores each session as a prefix of what was listed, bag b's session short of it.
    (A relaunch on a stored session would not do: the live loop detectors do not search the stored
    sessions, so bag b could not be joined.)"""
    final_store = st.store
    st.store = os.path.join(st.work, "probe", "s.db")
    st.start_slam("standalone:=false")
    st.play(os.path.join(survey, "a.bag"))
    wait_for(lambda: len(st.sessions()) >= 1 and st.sessions()[0][4] > 2, 30, 0.5)
    st.stop_group(st.launch)
    size = os.path.getsize(st.store)
    st.store = final_store
    cap_mb = (size + room_kb * 1024) / 1048576.0
    capped = config_with(st, "capped.yaml", {"backend_node": {"store_max_mb": cap_mb}})
    st.start_slam("standalone:=false", "config:=" + capped)
    import rospy
    rospy.init_node("fault_matrix", anonymous=True, disable_signals=True)
    backend = NodeStatus(": backend")
    wait_for(lambda: backend.latest, 30, 0.1)
    pid = st.manager_pid()
    rss0 = rss_mb(pid)
    two_sessions(st, survey)
    split_code, split_msg = status_code(st.call("split_session", 1))
    code, msg = status_code(st.call("join_sessions", 0, 1, 0))
    live = st.sessions()
    backend.fresh()
    failures = backend.value("store_failures")
    nodes, dead = st.alive()
    rss1 = rss_mb(pid)
    st.stop_group(st.launch)
    ok = integrity(st.store)
    grown = os.path.getsize(st.store)
    st.start_slam("standalone:=false")
    restored = st.sessions()
    st.stop_group(st.launch)
    live_kf = {s[0]: s[4] for s in live}
    restored_kf = {s[0]: s[4] for s in restored}
    held = (failures > 0 and split_code == 0 and code == 0 and len(live) >= 2 and live[0][3] == live[1][3] and nodes
            and not dead and ok == "ok" and grown <= size + (room_kb + 64) * 1024
            and all(0 <= restored_kf.get(s, 0) <= n for s, n in live_kf.items())
            and 0 < restored_kf.get(0, 0) and restored_kf.get(1, 0) < live_kf.get(1, 0))
    observed = ("bag a alone: %.0f kB, cap %.3f MB; bags a and b: store_failures %d; split_session 1: code %d%s; "
                "join_sessions 0 1: code %d%s; listed live %s; %d nodes alive%s; integrity %s; file %.0f kB; restored "
                "without the cap: %s; manager RSS %s -> %s") % (
        size / 1024.0, cap_mb, failures, split_code, (" '%s'" % split_msg[:60]) if split_code else "", code,
        (" '%s'" % msg[:60]) if code else "", [(s[0], s[3], s[4]) for s in live], len(nodes),
        "" if not dead else ", DEAD: %s" % dead, ok, grown / 1024.0, [(s[0], s[3], s[4]) for s in restored],
        fmt_mb(rss0), fmt_mb(rss1))
    row("live: the store full (store_max_mb = bag a's store + 64 kB) while bag b records, a split and a join",
        "store_failures > 0 on /diagnostics; keyframes, split and join go on in memory (OK); nodes alive; integrity "
        "ok; the file within the cap; restored: each session a prefix of the listed one, bag b's short", observed, held)

def case_export_links(st, survey):
    """The back-end's export service over links planted in its folder: at the writer's first
    temporary name of every file (<file>.tmp) and at the final name of one, each pointing at a file
    outside the export root. The export must answer OK, leave the files outside byte-identical,
    replace the final-name link by the file and never touch the planted temporaries."""
    root = os.path.join(st.work, "exports")
    folder = os.path.join(root, "ok3")
    outside = os.path.join(st.work, "outside")
    os.makedirs(folder)
    os.makedirs(outside)
    names = ["session_0." + ext for ext in ("tum", "kitti", "csv", "g2o")]
    victims = {}
    for i, name in enumerate(names):
        victim = os.path.join(outside, "tmp_%d" % i)
        with open(victim, "w") as f:
            f.write("precious %d\n" % i)
        victims[victim] = open(victim).read()
        os.symlink(victim, os.path.join(folder, name + ".tmp"))
    final = os.path.join(outside, "final")
    with open(final, "w") as f:
        f.write("precious final\n")
    victims[final] = open(final).read()
    os.symlink(final, os.path.join(folder, "session_0.csv"))
    st.start_slam("config:=" + config_with(st, "exports.yaml", {"backend_node": {"export_root": root}}))
    st.play(os.path.join(survey, "a.bag"))
    wait_for(lambda: len(st.sessions()) >= 1 and st.sessions()[0][4] > 2, 30, 0.5)
    res = st.call("export", "0", False, "ok3", "", 0.0, True, timeout=30)
    code, msg = status_code(res)
    nodes, dead = st.alive()
    st.stop_group(st.launch)
    untouched = all(open(v).read() == text for v, text in victims.items())
    regular = [n for n in names if os.path.isfile(os.path.join(folder, n)) and not os.path.islink(os.path.join(folder, n))]
    links_left = [n for n in names if os.path.islink(os.path.join(folder, n + ".tmp"))]
    with open(os.path.join(folder, "session_0.csv")) as f:
        csv_ok = f.readline().startswith("stamp_s,session,keyframe")
    held = code == 0 and untouched and len(regular) == len(names) and csv_ok and len(links_left) == len(names) and \
        nodes and not dead
    observed = ("export: code %d%s; files outside %s; %d of %d written as regular files (session_0.csv %s); planted "
                "temporary links left: %d; %d nodes alive%s") % (
        code, (" '%s'" % msg[:80]) if code else "", "byte-identical" if untouched else "CHANGED", len(regular),
        len(names), "a track" if csv_ok else "NOT a track", len(links_left), len(nodes),
        "" if not dead else ", DEAD: %s" % dead)
    row("live: export service over links planted at the temporary and the final names",
        "OK; the files outside the export root byte-identical; the final-name link replaced by the file; the planted "
        "temporaries left as they were; nodes alive", observed, held)


def case_bounds_and_paths(st, survey):
    """Arguments out of range and answers without paths: add_link with a yaw of 1e9 rad and with
    2^31-1 inliers, keyframe_features of session 2^31-1 and of a keyframe the store lacks, export
    into a folder outside the export root and of an unknown session. Each is refused naming its
    reason, and no answer carries the store's or the export root's path (the log has them)."""
    from geometry_msgs.msg import Pose2D
    root = os.path.join(st.work, "exports")
    os.makedirs(root)
    st.start_slam("config:=" + config_with(st, "exports.yaml", {"backend_node": {"export_root": root}}))
    two_sessions(st, survey)
    big = 2 ** 31 - 1
    cov = [1e-4, 0, 0, 0, 1e-4, 0, 0, 0, 1e-4]
    # Sessions, maps and states (keyframe counts may still grow while the back-end catches up).
    before = [s[:4] for s in st.sessions()]
    a, b = before[0][0], before[1][0]
    answers = [
        ("add_link yaw 1e9", st.call("add_link", a, 1, b, 1, Pose2D(0.0, 0.0, 1e9), cov, 0, False), "outside [-pi, pi]"),
        ("add_link inliers 2^31-1", st.call("add_link", a, 1, b, 1, Pose2D(0.0, 0.0, 0.1), cov, big, False),
         "inliers is more than"),
        ("keyframe_features 2^31-1 0", st.call("keyframe_features", big, 0, False), "outside the ids"),
        ("keyframe_features %d 999999" % a, st.call("keyframe_features", a, 999999, False), "not"),
        ("export into ../outside", st.call("export", str(a), False, "../outside", "", 0.0, True, timeout=30),
         "outside the export root"),
        ("export of an unknown session", st.call("export", "no_such", False, "x", "", 0.0, True, timeout=30), "no session"),
    ]
    after = [s[:4] for s in st.sessions()]
    nodes, dead = st.alive()
    st.stop_group(st.launch)
    paths = {st.store, os.path.realpath(st.store), root, os.path.realpath(root), st.work, os.path.realpath(st.work)}
    bad, notes = [], []
    for label, res, reason in answers:
        code, msg = status_code(res)
        notes.append("%s: code %d '%s'" % (label, code, msg[:90]))
        if code == 0 or reason not in msg:
            bad.append("%s: code %d, reason '%s' not named" % (label, code, reason))
        if any(p in msg for p in paths) or "/tmp" in msg:
            bad.append("%s: a path in the answer" % label)
    held = not bad and nodes and not dead and after == before and integrity(st.store) == "ok"
    observed = "%s%s; list_sessions %s; %d nodes alive%s" % (
        "; ".join(notes), "" if not bad else " -- " + "; ".join(bad), "unchanged" if after == before else "CHANGED",
        len(nodes), "" if not dead else ", DEAD: %s" % dead)
    row("live: arguments out of range (add_link yaw 1e9, inliers 2^31-1, keyframe_features 2^31-1) and answers "
        "without paths", "each refused naming its real reason; no answer carries the store's or the export root's "
        "path; sessions unchanged; nodes alive", observed, held)


def ecef(lat_deg, lon_deg):
    """WGS84 ECEF (m) of a point on the ellipsoid."""
    import math
    a, f = 6378137.0, 1.0 / 298.257223563
    e2 = f * (2 - f)
    phi, lam = math.radians(lat_deg), math.radians(lon_deg)
    n = a / math.sqrt(1 - e2 * math.sin(phi) ** 2)
    return (n * math.cos(phi) * math.cos(lam), n * math.cos(phi) * math.sin(lam), n * (1 - e2) * math.sin(phi))


def case_quoted_datum(st, survey):
    """A datum whose latitude is quoted in the config (backend_node/datum/latitude_deg: '43', text
    on the parameter server, as a hand-edited file or a launch file's <param type="str"> gives it),
    through slam.launch. The back-end must refuse to start with one line naming the key, before
    it opens the store (no file) or advertises anything; the other nodes stay up. (Read as 0
    degrees, the datum put earth -> map thousands of km off; the row then says how far.)"""
    lat, lon = 43.0951, 5.9307
    config = config_with(st, "quoted_datum.yaml",
                         {"backend_node": {"datum": {"latitude_deg": "%g" % lat, "longitude_deg": lon}}})
    st.launch = st.spawn(["roslaunch", "--wait", "uw_multislam", "slam.launch", "camera_mount:=0 0 0 0",
                          "store_path:=" + st.store, "config:=" + config], "launch.log")
    key = NS + "/backend_node/datum/latitude_deg = '%g'" % lat

    def fatal():
        with open(os.path.join(st.work, "launch.log"), errors="replace") as f:
            return [line.strip() for line in f if "not starting" in line]

    wait_for(lambda: fatal() or st.services_ready() or st.launch.poll() is not None, 90, 0.5)
    started = st.services_ready()
    off_note = ""
    if started:  # the datum was taken: how far is earth -> map from it?
        import rospy
        import tf2_ros
        rospy.init_node("fault_matrix", anonymous=True, disable_signals=True)
        buf = tf2_ros.Buffer()
        tf2_ros.TransformListener(buf)
        try:
            t = buf.lookup_transform("earth", "map", rospy.Time(0), rospy.Duration(20.0)).transform.translation
            want = ecef(lat, lon)
            off_note = "; earth -> map %.0f km from the datum" % (
                ((t.x - want[0]) ** 2 + (t.y - want[1]) ** 2 + (t.z - want[2]) ** 2) ** 0.5 / 1000.0)
        except Exception as e:
            off_note = "; no earth -> map (%s)" % type(e).__name__
    lines = fatal()
    nodes, dead = st.alive()
    store_made = os.path.exists(st.store)
    st.stop_group(st.launch)
    named = len(lines) == 1 and key in lines[0]
    held = named and not started and not store_made and len(nodes) >= 3 and not dead
    observed = "%s; back-end services %s%s; store file %s; %d nodes alive%s" % (
        ("FATAL: " + lines[0][lines[0].find("back-end"):][:160]) if lines else "no refusal in the log",
        "advertised" if started else "not advertised", off_note, "created" if store_made else "not created",
        len(nodes), "" if not dead else ", DEAD: %s" % dead)
    row("live: a quoted datum latitude ('43.0951') in the config",
        "the back-end refuses to start with one line naming backend_node/datum/latitude_deg, before the store is "
        "opened and before any service; the other nodes up", observed, held)


def case_dvl_relay(st, survey):
    """onboard.launch's DVL relay given a field the DVL's message type lacks
    (dvl_altitude:=m.pose.pose.position.zz on nav_msgs/Odometry): 15 messages at 10 Hz, fewer than
    its error period. One ERROR naming the field, the type missing it and that type's fields; no
    traceback, no second line within the period; the relay and the pipeline alive."""
    st.launch = st.spawn(["roslaunch", "--wait", "uw_multislam", "onboard.launch", "store_path:=none",
                          "camera_mount:=0 0 0 0", "dvl:=/dvl/data", "dvl_altitude:=m.pose.pose.position.zz"],
                         "launch.log")
    import rospy
    from nav_msgs.msg import Odometry
    from rosgraph_msgs.msg import Log
    relay = NS + "/dvl_altitude"
    rospy.init_node("fault_matrix", anonymous=True, disable_signals=True)
    logs = []
    sub = rospy.Subscriber("/rosout", Log, lambda m: logs.append(m) if m.name == relay else None, queue_size=1000)
    pub = rospy.Publisher("/dvl/data", Odometry, queue_size=100)

    def relay_uri():
        try:
            return st.master.lookupNode(relay)
        except Exception:  # not registered yet
            return None

    # A subscriber's connection is known by its publisher's URI: the relay's /rosout, then its /dvl/data.
    ready = wait_for(lambda: pub.get_num_connections() > 0 and relay_uri() in {
        c.endpoint_id for c in list(sub.impl.connections) if not c.done}, 60, 0.1)
    if not ready:
        return row("live: the DVL relay given a field its message type lacks", "runs to its verdict",
                   "the relay did not connect within 60 s (launch.log: %s)" % st.log_tail("launch.log"), False)
    for i in range(15):
        m = Odometry()
        m.header.stamp = rospy.Time.now()
        m.pose.pose.position.z = 2.0
        pub.publish(m)
        time.sleep(0.1)  # a DVL's pace (10 Hz)
    errors = lambda: [m.msg for m in logs if m.level >= Log.ERROR]
    wait_for(lambda: errors(), 20, 0.1)
    wait_for(lambda: len(errors()) > 1, 3, 0.1)  # a second line would come as fast as the first
    said = errors()
    nodes, dead = st.alive()
    st.stop_group(st.launch)
    first = said[0] if said else ""
    held = (len(said) == 1 and "reads 'zz', which m.pose.pose.position (geometry_msgs/Point) does not have (its "
            "fields: x, y, z)" in first and not any("Traceback" in m.msg or "bad callback" in m.msg for m in logs)
            and relay in nodes and not dead)
    observed = "%d ERROR line(s) from the relay for 15 messages%s; traceback: %s; %d nodes alive%s" % (
        len(said), (": " + first[:170] + "...") if first else "", "yes" if any("Traceback" in m.msg for m in logs)
        else "none", len(nodes), "" if not dead else ", DEAD: %s" % dead)
    row("live: the DVL relay (onboard.launch dvl:=) given a field its message type lacks",
        "one ERROR naming the field, the type missing it and its fields (then at most one per 10 s); no traceback; "
        "the relay and the nodes alive", observed, held)


def hostile_keyframe(session, keyframe=0):
    """A well-formed Keyframe message (one feature) naming any session, as a faulty vehicle or a
    stray publisher could send it."""
    import rospy
    from geometry_msgs.msg import Pose2D
    from uw_multislam.msg import Keyframe
    m = Keyframe()
    m.header.stamp = rospy.Time.now()
    m.header.frame_id = "camera"
    m.session, m.keyframe, m.frame_index, m.altitude_m = session, keyframe, keyframe, 2.0
    m.width, m.height, m.fx, m.fy, m.cx, m.cy = 320, 240, 300.0, 300.0, 159.5, 119.5
    m.u_px, m.v_px, m.response = [10.0], [20.0], [1.0]
    m.descriptor_size = 128
    m.descriptors = bytes(128)
    m.odometry_pose = Pose2D(0.0, 0.0, 0.0)
    m.status, m.scale = Keyframe.FIRST, 1.0
    return m


def case_ids_and_inputs(st, survey):
    """Where session ids, names, links and the store's files enter: a Keyframe message naming
    session 999999 (before the first bag and again between the two), start_session named "7" and
    one with no keyframe after it, an add_link of 1,000 km with a 1 cm sigma, then a clean
    shutdown with a reader's connection open (the WAL) and a restart (the next id)."""
    import rospy
    from geometry_msgs.msg import Pose2D
    from uw_multislam.msg import Keyframe, Status
    st.start_slam()
    rospy.init_node("fault_matrix", anonymous=True, disable_signals=True)
    back, odo = NodeStatus(": backend"), NodeStatus()
    published = []
    rospy.Subscriber(NS + "/keyframes", Keyframe, lambda m: published.append(m) if m._connection_header.get(
        "callerid", "") != rospy.get_name() else None, queue_size=1000)
    stray = rospy.Publisher(NS + "/keyframes", Keyframe, queue_size=10)

    def subscribers():  # every node the master lists on the topic, this one's subscriber included
        return [n for t, nodes in st.master.getSystemState()[1] if t == NS + "/keyframes" for n in nodes]
    wait_for(lambda: back.latest and odo.latest and subscribers() and stray.get_num_connections() == len(subscribers()),
             30, 0.1)

    def ours():
        n = {}
        for k in published:
            n[k.session] = n.get(k.session, 0) + 1
        return n

    def listed():
        return {s[0]: s[4] for s in st.sessions()}

    def caught_up():  # the odometry's keyframes all received here and listed by the back-end
        odo.fresh()
        return odo.value("keyframes") == len(published) and listed() == ours()
    stray.publish(hostile_keyframe(999999))
    st.play(os.path.join(survey, "a.bag"))
    wait_for(caught_up, 60, 0.2)
    stray.publish(hostile_keyframe(999999, 1))
    stray.publish(hostile_keyframe(500000))
    st.play(os.path.join(survey, "b.bag"))
    wait_for(caught_up, 60, 0.2)
    kept, sent = listed(), ours()
    back.fresh()
    unopened = back.value("keyframes_unopened")
    digits = status_code(st.call("start_session", "7"))
    res = st.call("start_session", "dive 3")
    empty_id = res.session
    empty = [s for s in st.sessions() if s[0] == empty_id]
    cov = [1e-4, 0, 0, 0, 1e-4, 0, 0, 0, 1e-4]
    far = status_code(st.call("add_link", 0, 1, 1, 1, Pose2D(1e6, 0.0, 0.0), cov, 0, False))
    # A monitoring tool's read-only connection stays open across the shutdown: the back-end's is
    # then not the last one, and SQLite leaves the WAL to its last connection.
    reader = ro_connect(st.store)
    reader.execute("SELECT count(*) FROM keyframes").fetchone()
    st.stop_group(st.launch)
    clean = st.launch.returncode
    wal = os.path.getsize(st.store + "-wal") if os.path.exists(st.store + "-wal") else 0
    reader.close()
    ok = integrity(st.store)
    st.start_slam()
    restored = [s[0] for s in st.sessions()]
    after = st.call("start_session", "after restart").session
    st.stop_group(st.launch)
    bad = []
    if kept != sent or sorted(sent) != [0, 1]:
        bad.append("sessions %s, the odometry published %s" % (kept, sent))
    if unopened != 3:
        bad.append("keyframes_unopened %d, not 3" % unopened)
    if digits[0] != Status.INVALID_ARGUMENT or "digits" not in digits[1]:
        bad.append("start_session '7': code %d '%s'" % digits)
    if res.status.code != Status.OK or empty_id != 2 or not empty or empty[0][4] != 0:
        bad.append("start_session 'dive 3': code %d, session %d, listed %s" % (res.status.code, empty_id, empty))
    if far[0] != Status.INVALID_ARGUMENT or "at most" not in far[1]:
        bad.append("add_link of 1000 km: code %d '%s'" % far)
    if wal != 0 or ok != "ok":
        bad.append("after the clean exit: WAL %d bytes, integrity %s" % (wal, ok))
    if restored != [0, 1] or after != 2:
        bad.append("restarted: sessions %s, start_session gave %d" % (restored, after))
    observed = ("keyframes of sessions 999999 and 500000 refused (keyframes_unopened %d); sessions %s as published %s; "
                "start_session '7': code %d '%s'; 'dive 3' (no keyframe): session %d listed with %s keyframes; "
                "add_link 1000 km: code %d '%s'; clean exit (status %s): WAL %d bytes, integrity %s; restarted: "
                "sessions %s, start_session gave %d%s") % (
        unopened, kept, sent, digits[0], digits[1][:80], empty_id, empty[0][4] if empty else "no", far[0],
        far[1][:110], clean, wal, ok, restored, after, "" if not bad else " -- " + "; ".join(bad))
    row("live: a keyframe of session 999999, a session named '7', one without keyframes, a 1000 km link, the WAL "
        "after a clean exit (a reader open), a restart",
        "the stray keyframes refused and counted, every keyframe of the odometry kept in sessions 0 and 1; '7' refused "
        "(digits only); the empty session listed with 0 keyframes; the link refused naming its bound; WAL 0 bytes "
        "after a clean exit with a reader open; "
        "after the restart sessions 0 and 1 and the next id 2", observed, not bad)


CASES = {"service_misuse": case_service_misuse, "bounds_and_paths": case_bounds_and_paths, "concurrent": case_concurrent, "kill_manager": case_kill_manager,
         "bad_images": case_bad_images, "kill_manager_moments": case_kill_manager_moments,
         "replay_rates": case_replay_rates, "silent_altitude": case_silent_altitude, "burst": case_burst,
         "store_cap": case_store_cap, "export_links": case_export_links, "quoted_datum": case_quoted_datum,
         "dvl_relay": case_dvl_relay, "ids_and_inputs": case_ids_and_inputs,
         "nav_clock_and_mount": case_nav_clock_and_mount}


def main():
    p = argparse.ArgumentParser()
    p.add_argument("case", choices=sorted(CASES))
    p.add_argument("--survey", required=True)
    p.add_argument("--dir", required=True)
    a = p.parse_args()
    st = None
    try:
        st = Stack(a.dir)
        CASES[a.case](st, a.survey)
    finally:
        if st is not None:
            st.stop()
    return 0


if __name__ == "__main__":
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(1))  # finally: stop the master and the launch
    sys.exit(main())
