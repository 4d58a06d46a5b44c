#!/usr/bin/python3
"""Records a live or replayed SLAM run into the offline runner's files (offline_slam --help, "The offline
runner's contract"), so that evaluate.py scores a ROS run like an offline_slam one.

    record_run.py --out OUT [--session-dir DIR [--bag-start SEC] ...] [--ns /uw_multislam]

Subscribes to the back-end's outputs and writes them into OUT as they come, until it is stopped
(SIGINT / SIGTERM / rosnode kill), or with --until-idle SEC until nothing has arrived for SEC seconds
after the first keyframe. A recorder that is killed (SIGKILL, a crash) leaves every row it had
received: odometry.csv, loops.csv and loop_poses.csv are appended and flushed row by row, and
trajectory.csv and pieces.csv, which optimisations change, are replaced whole (a temporary file
renamed over them) at most once a second while they change, and once more at the end:

  odometry.csv    session,index,x_m,y_m,yaw_rad            Keyframe.odometry_pose (session frame)
  trajectory.csv  session,index,map,x_m,y_m,yaw_rad        the last paths/session_<id> (nav_msgs/Path
                                                            in the map frame, one pose per keyframe in
                                                            order) and the map of the last
                                                            session_trajectory of each session; the
                                                            paths give base_link in the z-up map, the
                                                            file the camera in image axes as
                                                            offline_slam (camera_pose())
  loops.csv       session_a,index_a,session_b,index_b,kind,inliers    every Loop message
  loop_poses.csv  session_a,index_a,session_b,index_b,x_m,y_m,yaw_rad the loops' measured X_b^a
  pieces.csv      session,piece,store_session,first_index,last_index,keyframes,map  one row per ROS
                  session: its folder, its piece in the folder (a tracking loss splits a folder), its
                  id, the folder indexes it spans and its map (evaluate.py scores pieces apart)
  inputs.csv      session,folder,frames,first_stamp_s,last_stamp_s,altitude_mean_m  with --session-dir:
                                                            the folders, for evaluate.py's check

Numbering. The contract numbers sessions by dataset folder and frames by their frames.csv index.
With --session-dir (the folders whose bags are played, in order) a keyframe is placed by its stamp:
frame k of folder i was played at bag-start_i + stamp_s, bag-start_i being the start time its bag
was written with (folder_to_bag --start-time; make_survey and folder_to_bag use 1700000000 by
default). Give --bag-start once for all folders (their stamps must then differ, as make_survey's
do), or once per --session-dir, in the same order, when the folders' stamps overlap (two folders
both starting at stamp_s 0, bags written with different start times). So a session the odometry
starts inside one folder (tracking loss) keeps that folder's number, as offline_slam does, and
dropped frames do not shift indexes. Without folders the ROS session id and Keyframe.frame_index
are used as they are. A map is named by its first session, converted to the folder number the same
way.

Sessions are found as they appear: a new session id in keyframes or session_trajectory opens a
subscriber to its latched paths/session_<id>. Wall time only (no rospy.sleep): under use_sim_time
the clock stops with the bag.
"""
import argparse
import csv
import io
import math
import os
import sys
import tempfile
import threading
import time

# --help works without a sourced workspace (setup.bash puts the package's messages on PYTHONPATH);
# a run without them stops with a line that says so.
try:
    import rospy
    from nav_msgs.msg import Path
    from uw_multislam.msg import Keyframe, Loop, SessionTrajectory
    ROS_IMPORT_ERROR = None
except ImportError as e:
    ROS_IMPORT_ERROR = e


def yaw_of(q):
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def camera_pose(x, y, yaw, mount):
    """The camera's pose in the core's frame (image axes, z into the seabed) from base_link's pose
    in the z-up map, the mount being (x, y, yaw) of the camera in base_link:
    zUp(vehicle (+) base_from_camera), as core::cameraFromVehicle (core/geometry/vehicle_frame.h)."""
    mx, my, myaw = mount
    cx = x + math.cos(yaw) * mx - math.sin(yaw) * my
    cy = y + math.sin(yaw) * mx + math.cos(yaw) * my
    c = -(yaw + myaw)
    return cx, -cy, math.atan2(math.sin(c), math.cos(c))


def mount_of(camera_frame, timeout_s=5.0):
    """The camera's (x, y, yaw) in base_link from tf, base_link -> `camera_frame` (the images'
    frame_id; the odometry looks the same transform up), polled on wall time (the clock may not run
    yet). Without it within timeout_s: the camera at base_link, said on stderr."""
    import tf2_ros
    buffer = tf2_ros.Buffer()
    listener = tf2_ros.TransformListener(buffer)  # noqa: F841 (fills the buffer)
    deadline = time.time() + timeout_s
    while not buffer.can_transform("base_link", camera_frame, rospy.Time(0)):
        if time.time() > deadline:
            print("[record_run] no base_link -> %s in tf: trajectory.csv assumes the camera at base_link" % camera_frame,
                  file=sys.stderr, flush=True)
            return 0.0, 0.0, 0.0
        time.sleep(0.05)
    t = buffer.lookup_transform("base_link", camera_frame, rospy.Time(0)).transform
    q = t.rotation
    # The yaw of the image columns: the optical frame's x axis in base_link's plane.
    return t.translation.x, t.translation.y, math.atan2(2 * (q.x * q.y + q.w * q.z), 1 - 2 * (q.y * q.y + q.z * q.z))


DEFAULT_BAG_START = 1700000000.0  # folder_to_bag's and make_survey's default start time


def stamp_key(seconds):
    return int(round(seconds * 1000.0))  # milliseconds: bag stamps are start + stamp_s


def bag_starts_of(folders, bag_starts):
    """One bag start per folder: none given, the default; one, for all; else one per folder."""
    if not bag_starts:
        return [DEFAULT_BAG_START] * len(folders)
    if len(bag_starts) == 1:
        return bag_starts * len(folders)
    if len(bag_starts) != len(folders):
        raise ValueError("%d --bag-start values for %d --session-dir folders (%s): give one for all, or one per "
                         "folder in the same order" % (len(bag_starts), len(folders), ", ".join(folders)))
    return list(bag_starts)


def read_frames(folder):
    """[(frame index, stamp_s, altitude_m)] of a dataset folder's frames.csv; every error names the file."""
    path = os.path.join(folder, "frames.csv")
    if not os.path.isdir(folder):
        raise ValueError("%s: --session-dir is not a folder" % folder)
    try:
        with open(path, newline="") as f:
            reader = csv.DictReader(f)
            missing = {"index", "stamp_s", "altitude_m"} - set(reader.fieldnames or [])
            if missing:
                raise ValueError("%s: no column %s (a dataset folder's frames.csv has index,image,stamp_s,"
                                 "altitude_m)" % (path, " and ".join(sorted(missing))))
            frames = []
            for line, row in enumerate(reader, start=2):
                try:
                    frames.append((int(row["index"]), float(row["stamp_s"]), float(row["altitude_m"])))
                except (TypeError, ValueError):
                    raise ValueError("%s:%d: cannot read index '%s' / stamp_s '%s' / altitude_m '%s'" % (
                        path, line, row["index"], row["stamp_s"], row["altitude_m"])) from None
    except OSError as e:
        raise ValueError("%s: %s" % (path, e.strerror or e)) from None
    if not frames:
        raise ValueError("%s: no frames" % path)
    return frames


def read_frame_stamps(folders, bag_starts):
    """(stamp in ms) -> (folder number, frame index) over every frame of every folder, frame k of folder
    i at bag_starts[i] + stamp_s. Raises ValueError naming the folder(s) when a stamp is not unique."""
    table = {}
    for number, (folder, start) in enumerate(zip(folders, bag_starts_of(folders, bag_starts))):
        for index, stamp_s, _ in read_frames(folder):
            key = stamp_key(start + stamp_s)
            if key in table:
                other, other_index = table[key]
                if other == number:
                    raise ValueError("%s: frames %d and %d have the same stamp %.3f s" % (
                        os.path.join(folder, "frames.csv"), other_index, index, stamp_s))
                raise ValueError(
                    "%s (frame %d) and %s (frame %d) would be played at the same time %.3f: their stamps overlap. "
                    "Give each folder the start time its bag was written with (folder_to_bag --start-time), "
                    "--bag-start once per --session-dir, in the same order" % (
                        folders[other], other_index, folder, index, key / 1000.0))
            table[key] = (number, index)
    return table


def run_inputs(folders):
    """inputs.csv's rows, as offline_slam writes them (core::writeRunInputs): evaluate.py compares them
    with the folders it is given. (session, folder, frames, first stamp_s, last stamp_s, mean altitude)."""
    rows = []
    for number, folder in enumerate(folders):
        frames = read_frames(folder)
        altitudes = [a for _, _, a in frames if math.isfinite(a)]
        rows.append((number, folder, len(frames), frames[0][1], frames[-1][1],
                     sum(altitudes) / len(altitudes) if altitudes else math.nan))
    return rows


def stamp_ranges(folders, table):
    """'folder: first..last' of the placed stamps of each folder, for messages."""
    ranges = []
    for number, folder in enumerate(folders):
        keys = [k for k, v in table.items() if v[0] == number]
        ranges.append("%s: %.3f..%.3f" % (folder, min(keys) / 1000.0, max(keys) / 1000.0))
    return "; ".join(ranges)


def _umask():
    mask = os.umask(0)
    os.umask(mask)
    return mask


UMASK = _umask()  # once, before any thread: a replaced file gets the mode open() would have given it


def write_replacing(path, text):
    """Replaces the file at `path` with `text` whole: written to a temporary file in the same folder,
    flushed to disk and renamed over it, so that a reader, or a recorder killed meanwhile, finds the
    old file or the new one and never half of one. (The one place to swap for the Python tools'
    shared safe writer.)"""
    fd, tmp = tempfile.mkstemp(prefix="." + os.path.basename(path) + ".", suffix=".tmp",
                               dir=os.path.dirname(path) or ".")
    try:
        os.fchmod(fd, 0o666 & ~UMASK)  # mkstemp's file is 0600
        with os.fdopen(fd, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


class RunFiles:
    """The run's files in OUT, kept up to date while the run goes on, so that a recorder killed
    (SIGKILL, a crash, the machine's power) leaves what it had received. The rows of odometry.csv,
    loops.csv and loop_poses.csv never change once their message has come: each is appended and
    flushed at once. trajectory.csv and pieces.csv change with every optimisation and new session:
    they are replaced whole (write_replacing) while they change, at most once a second, and at the
    end. inputs.csv is written at the start. A new run replaces the files of an earlier one."""
    APPENDED = {"odometry.csv": "session,index,x_m,y_m,yaw_rad",
                "loops.csv": "session_a,index_a,session_b,index_b,kind,inliers",
                "loop_poses.csv": "session_a,index_a,session_b,index_b,x_m,y_m,yaw_rad"}

    def __init__(self, out):
        os.makedirs(out, exist_ok=True)
        self.out = out
        self.files = {}
        for name, header in self.APPENDED.items():
            self.files[name] = open(os.path.join(out, name), "w")
            self.append(name, header)

    def append(self, name, row):
        f = self.files[name]
        f.write(row + "\n")
        f.flush()  # in the operating system's hands: a killed process loses none of it

    def replace(self, name, text):
        write_replacing(os.path.join(self.out, name), text)

    def close(self):
        for f in self.files.values():
            f.close()


def inputs_text(inputs):
    rows = ["session,folder,frames,first_stamp_s,last_stamp_s,altitude_mean_m"]
    for n, folder, frames, first, last, altitude in inputs:
        out = io.StringIO()
        csv.writer(out, lineterminator="").writerow((n, folder, frames, "%.6f" % first, "%.6f" % last,
                                                     "%.6f" % altitude))
        rows.append(out.getvalue())
    return "\n".join(rows) + "\n"


class Recorder:
    """What the run has received, written into its RunFiles as it comes. The ROS callbacks
    (subscribe()) and the main loop (refresh(), finish()) take the lock."""

    REPLACE_PERIOD_S = 1.0  # trajectory.csv and pieces.csv replaced at most this often while they change

    def __init__(self, files, frame_stamps, mount=(0.0, 0.0, 0.0), describe_folders="", inputs=None):
        self.files = files
        self.mount = mount  # the camera in base_link: paths give base_link, the files the camera
        self.frame_stamps = frame_stamps  # None: ROS ids as they are
        self.lock = threading.Lock()
        self.keyframes = {}  # (ros session, keyframe id) -> Keyframe fields we keep
        self.waiting_loops = []  # loops that came before a keyframe they name
        self.loops_written = 0
        self.loops_missing = 0  # loops naming a keyframe not placed by stamp
        self.paths = {}  # ros session -> last Path
        self.maps = {}  # ros session -> map (ros session id) of its last session_trajectory
        self.path_subs = {}
        self.unplaced = 0
        self.last_message = None  # wall time (time.time()) of the last message
        self.describe_folders = describe_folders  # the folders' stamp ranges, for the unplaced warning
        self.changed, self.replaced_at = True, 0.0  # trajectory.csv and pieces.csv due
        self.trajectory_rows = self.trajectory_missing = 0
        self.ns = None  # subscribe() sets it; without, messages come from the caller (tests)
        if inputs is not None:
            files.replace("inputs.csv", inputs_text(inputs))
        self.refresh(force=True)  # an earlier run's files replaced from the start

    def subscribe(self, ns):
        self.ns = ns.rstrip("/")
        rospy.Subscriber(self.ns + "/keyframes", Keyframe, self.on_keyframe, queue_size=1000, buff_size=2 ** 24)
        rospy.Subscriber(self.ns + "/loops", Loop, self.on_loop, queue_size=1000)
        rospy.Subscriber(self.ns + "/session_trajectory", SessionTrajectory, self.on_trajectory, queue_size=100)

    def watch(self, session):
        """Subscribes to a session's latched path once (caller holds the lock)."""
        if session in self.path_subs:
            return
        self.path_subs[session] = rospy.Subscriber(
            "%s/paths/session_%d" % (self.ns, session), Path, lambda msg: self.on_path(session, msg), queue_size=10)

    def place(self, session, frame_index, stamp):
        """(folder number, frame index) of a keyframe."""
        if self.frame_stamps is None:
            return session, frame_index
        found = self.frame_stamps.get(stamp_key(stamp.to_sec()))
        if found is None:
            self.unplaced += 1
            if self.unplaced == 1:
                print("[record_run] keyframe %d of session %d (stamp %.3f) is no frame of the folders (%s): wrong "
                      "--bag-start or --session-dir? Such keyframes are left out" % (
                          frame_index, session, stamp.to_sec(), self.describe_folders), file=sys.stderr, flush=True)
        return found

    def on_keyframe(self, msg):
        with self.lock:
            self.last_message = time.time()
            if (msg.session, msg.keyframe) in self.keyframes:
                return  # sent twice: written once
            if not any(s == msg.session for s, _ in self.keyframes):
                print("[record_run] session %d: first keyframe" % msg.session, flush=True)
            if self.ns is not None:
                self.watch(msg.session)
            key = self.place(msg.session, msg.frame_index, msg.header.stamp)
            self.keyframes[(msg.session, msg.keyframe)] = {"key": key, "stamp": msg.header.stamp}
            if key is not None:
                pose = msg.odometry_pose
                self.files.append("odometry.csv", "%d,%d,%.6f,%.6f,%.7f" % (key + (pose.x, pose.y, pose.theta)))
            self.changed = True  # pieces.csv
            waiting, self.waiting_loops = self.waiting_loops, []
            for loop in waiting:
                self.add_loop(loop)

    def on_loop(self, msg):
        with self.lock:
            self.last_message = time.time()
            self.add_loop(msg)

    def add_loop(self, loop):
        """Writes a loop's rows, or keeps it until the keyframes it names have come (caller holds the lock)."""
        a = self.key_of(loop.session_a, loop.keyframe_a)
        b = self.key_of(loop.session_b, loop.keyframe_b, loop.header.stamp)
        if a is None or b is None:
            came = lambda s, k: (s, k) in self.keyframes  # noqa: E731
            # An end that will never be placed: its keyframe came and is no frame of the folders (nor
            # is the new keyframe's stamp). Left out like that keyframe; else it waits for its keyframe.
            if (a is None and came(loop.session_a, loop.keyframe_a)) or \
                    (b is None and (came(loop.session_b, loop.keyframe_b) or self.frame_stamps is not None)):
                self.loops_missing += 1
            else:
                self.waiting_loops.append(loop)
            return
        kind = "local" if loop.kind == Loop.LOCAL else "global"
        self.files.append("loops.csv", "%d,%d,%d,%d,%s,%d" % (a + b + (kind, loop.inliers)))
        self.files.append("loop_poses.csv", "%d,%d,%d,%d,%.6f,%.6f,%.7f" % (
            a + b + (loop.pose.x, loop.pose.y, loop.pose.theta)))
        self.loops_written += 1

    def on_trajectory(self, msg):
        with self.lock:
            self.last_message = time.time()
            self.maps[msg.session] = msg.map
            self.changed = True
            if self.ns is not None:
                self.watch(msg.session)

    def on_path(self, session, msg):
        with self.lock:
            self.last_message = time.time()
            self.paths[session] = msg
            self.changed = True

    def idle_for(self):
        """Seconds since the last message, or 0 before the first keyframe."""
        with self.lock:
            return 0.0 if not self.keyframes else time.time() - self.last_message

    def key_of(self, session, keyframe, stamp=None):
        kf = self.keyframes.get((session, keyframe))
        if kf is not None:
            return kf["key"]
        if stamp is not None and self.frame_stamps is not None:
            return self.frame_stamps.get(stamp_key(stamp.to_sec()))
        return None

    def refresh(self, force=False):
        """trajectory.csv and pieces.csv replaced when they changed (at most once per REPLACE_PERIOD_S
        unless forced)."""
        with self.lock:
            if not (force or self.changed and time.time() - self.replaced_at >= self.REPLACE_PERIOD_S):
                return
            first_key = {}  # ros session -> its first keyframe's folder number
            for (session, keyframe), kf in sorted(self.keyframes.items()):
                if kf["key"] is not None and session not in first_key:
                    first_key[session] = kf["key"][0]
            piece, label = pieces_and_map_labels(first_key)
            rows, missing = ["session,index,map,x_m,y_m,yaw_rad"], 0
            for session, path in sorted(self.paths.items()):
                ros_map = self.maps.get(session, session)
                map_id = label.get(ros_map, ros_map)
                for k, p in enumerate(path.poses):
                    key = self.key_of(session, k, p.header.stamp)
                    if key is None:
                        missing += 1
                        continue
                    x, y, yaw = camera_pose(p.pose.position.x, p.pose.position.y, yaw_of(p.pose.orientation), self.mount)
                    rows.append("%d,%d,%d,%.6f,%.6f,%.7f" % (key[0], key[1], map_id, x, y, yaw))
            self.files.replace("trajectory.csv", "\n".join(rows) + "\n")
            self.trajectory_rows, self.trajectory_missing = len(rows) - 1, missing
            pieces = ["session,piece,store_session,first_index,last_index,keyframes,map"]
            for session in sorted(piece):
                indexes = [kf["key"][1] for (s, _), kf in self.keyframes.items() if s == session and kf["key"]]
                ros_map = self.maps.get(session, session)
                pieces.append("%d,%d,%d,%d,%d,%d,%d" % (first_key[session], piece[session], session, min(indexes),
                                                        max(indexes), len(indexes), label.get(ros_map, ros_map)))
            self.files.replace("pieces.csv", "\n".join(pieces) + "\n")
            self.changed, self.replaced_at = False, time.time()

    def finish(self):
        """The last trajectory and pieces, the files closed, and the summary line; returns the counts."""
        self.refresh(force=True)
        with self.lock:
            self.files.close()
            counts = {"odometry": sum(1 for kf in self.keyframes.values() if kf["key"] is not None),
                      "trajectory": self.trajectory_rows, "loops": self.loops_written,
                      "missing": self.trajectory_missing + self.loops_missing + len(self.waiting_loops)}
            sessions = sorted({s for s, _ in self.keyframes})
            print("[record_run] %d sessions %s, %d keyframes (%d odometry rows), %d trajectory rows from %d paths, "
                  "%d loops; %d keyframes not placed by stamp, %d rows skipped -> %s" % (
                      len(sessions), sessions, len(self.keyframes), counts["odometry"], counts["trajectory"],
                      len(self.paths), counts["loops"], self.unplaced, counts["missing"], self.files.out), flush=True)
            return counts


def pieces_and_map_labels(folder_of):
    """For ROS sessions (id -> folder number of their first keyframe): each one's piece number in
    its folder (0, 1, ... in id order: a tracking loss split the folder) and the label of the map
    it names, as offline_slam labels them (core::writeRunOutputs): a first piece's map takes the
    folder's number, a later piece's the next number no folder uses."""
    piece, label = {}, {}
    next_label = max(folder_of.values(), default=-1) + 1
    for session in sorted(folder_of):
        earlier = [s for s in piece if folder_of[s] == folder_of[session]]
        piece[session] = len(earlier)
        if earlier:
            label[session], next_label = next_label, next_label + 1
        else:
            label[session] = folder_of[session]
    return piece, label


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", required=True, help="directory for the run's CSV files")
    parser.add_argument("--session-dir", action="append", default=[], metavar="DIR",
                        help="dataset folder whose bag is played, in order (repeat); places keyframes by stamp")
    parser.add_argument("--bag-start", type=float, action="append", default=[], metavar="SEC",
                        help="time of stamp_s = 0 in the bags (folder_to_bag --start-time): once for all folders, "
                             "or once per --session-dir in the same order (default 1700000000, make_survey's)")
    parser.add_argument("--ns", default="/uw_multislam", help="namespace of the SLAM topics")
    parser.add_argument("--camera-frame", default="camera",
                        help="the images' frame_id: base_link -> it in tf places the camera (default camera)")
    parser.add_argument("--ready-file", help="created once subscribed (for scripts that wait for it)")
    parser.add_argument("--until-idle", type=float, metavar="SEC",
                        help="write and exit once no message has arrived for SEC seconds (wall time) after the "
                             "first keyframe, e.g. when the bags are played; default: until stopped")
    args = parser.parse_args(rospy.myargv()[1:] if not ROS_IMPORT_ERROR else None)
    if ROS_IMPORT_ERROR:
        sys.exit("record_run: %s (source the workspace's devel/setup.bash or install/setup.bash first)" %
                 ROS_IMPORT_ERROR)
    if args.bag_start and not args.session_dir:
        parser.error("--bag-start places keyframes in --session-dir folders: give the folders too")
    try:
        frame_stamps = read_frame_stamps(args.session_dir, args.bag_start) if args.session_dir else None
        inputs = run_inputs(args.session_dir) if args.session_dir else None
    except ValueError as e:
        sys.exit("record_run: %s" % e)

    try:
        files = RunFiles(args.out)
    except OSError as e:
        sys.exit("record_run: --out %s: %s" % (args.out, e.strerror or e))
    rospy.init_node("record_run", disable_signals=False)
    recorder = Recorder(files, frame_stamps, mount_of(args.camera_frame),
                        stamp_ranges(args.session_dir, frame_stamps) if frame_stamps else "", inputs)
    recorder.subscribe(args.ns)
    if args.ready_file:
        open(args.ready_file, "w").close()
    # Until SIGINT / SIGTERM / rosnode kill, or --until-idle; wall time: under use_sim_time the clock
    # stops with the bag.
    while not rospy.is_shutdown() and (args.until_idle is None or recorder.idle_for() <= args.until_idle):
        recorder.refresh()
        time.sleep(0.2)
    recorder.finish()


if __name__ == "__main__":
    main()
