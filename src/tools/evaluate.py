#!/usr/bin/python3
"""evaluate: score an offline_slam run against ground truth.

Reads the run's output directory (odometry.csv, trajectory.csv, loops.csv, timing.csv; see
the offline runner contract in offline_slam --help) and the dataset folders of its sessions (gt.csv,
frames.csv, camera.yaml; session number N = the N-th folder), plus the optional world_gt.csv
(every session in one world frame) and loops_gt.csv (the revisits a detector should find).
Writes metrics.csv, metrics.json, metrics.md and PNG plots into the report directory and prints
the markdown tables.

Estimates and frames
  odometry  odometry.csv; each session in its own frame.
  slam      trajectory.csv; each keyframe in the frame of its map.
  The ground truth is expressed in the estimate's frame without any fitting: a session's frame
  is the gt pose of its first keyframe (lowest index); a map's frame is the gt pose of the
  first keyframe of its lowest-numbered session. A map holding one session uses that session's
  gt.csv; a map holding several needs world_gt.csv (without it, its absolute metrics are n/a).
  Relative ground truth between two frames of one session comes from gt.csv, between sessions
  from world_gt.csv.

Metrics (per session, for both estimates; keyframes in index order)
  n_keyframes          keyframes of the session in the estimate.
  path_length_m        sum of distances between consecutive gt keyframe positions.
  ate_rmse_m           RMSE of estimated minus gt keyframe positions, no alignment.
  ate_aligned_rmse_m   the same after the best 2-D rigid (SE(2), no scale) least-squares
                       alignment of the estimate onto the gt.
  end_drift_pct        distance between the last estimated and gt keyframe positions, in % of
                       path_length_m.
  rpe_trans_rmse_m     RMSE over consecutive keyframe pairs (i, j) of |t_gt(j|i) - t_est(j|i)|,
                       t(j|i) = position of j expressed in the frame of pose i (rotated by -yaw_i).
  rpe_rot_rmse_deg     RMSE of (yaw_est(j|i) - yaw_gt(j|i)), each difference wrapped to (-pi, pi].
  ek_intra_m           the paper's e_k (35): mean of |t_gt(j|i) - t_est(j|i)| over the
                       loops_gt.csv pairs of this session whose two frames are keyframes of the
                       estimate (ek_intra_pairs = number of pairs used).
  ek_inter_m           the same over loops_gt.csv pairs between this session and another session
                       of the same map (slam only; needs world_gt.csv), ek_inter_pairs.
  Consecutive pairs and e_k pairs are used only when both keyframes lie in the same map.

Metrics (per map, slam)
  n_sessions, n_keyframes, ate_rmse_m, ate_aligned_rmse_m over all keyframes of the map,
  ek_intra_m / ek_inter_m (+ _pairs) over the loops_gt.csv pairs inside the map.

Metrics (loops, rows intra / inter / all)
  accepted             distinct unordered pairs in loops.csv.
  correct              when the run has loop_poses.csv (offline_slam writes it: the measured
                       pose of b in a, columns session_a,index_a,session_b,index_b,x_m,y_m,
                       yaw_rad), accepted pairs whose measured pose is within 10 % of the
                       footprint height and 5 deg of the gt relative pose: a geometrically
                       right loop. Otherwise accepted pairs whose gt distance between image
                       centres is below the true-loop distance: --loop-true-dist, or by
                       default the image footprint height image_height * altitude / fy
                       averaged over the two frames (their altitudes from frames.csv), i.e.
                       the images overlap. Inter-session pairs need world_gt.csv.
  precision            correct / accepted (n/a when nothing was accepted or a pair cannot be
                       judged).
  gt_pairs             distinct pairs in loops_gt.csv (raw count).
  gt_pairs_keyframes   of those, pairs whose two frames are both keyframes of the run.
  found                accepted pairs among gt_pairs_keyframes.
  recall               found / gt_pairs_keyframes.

Timing: timing.csv copied as rows (scope timing, id = stage).

The run must be the run of the folders given, else it is refused with the reason: one folder per
session of the run (no folder without keyframes, no session without a folder), every keyframe a
frame of its folder's gt.csv, and, when the run has inputs.csv (offline_slam and record_run.py
--session-dir write it: session,folder,frames,first_stamp_s,last_stamp_s,altitude_mean_m), each
session's folder with the same number of frames, first and last stamp_s and mean altitude.

Outputs
  metrics.csv   long format: scope,id,estimate,metric,value (value n/a when not computable)
  metrics.json  {scope: {id: {estimate: {metric: value}}}}, n/a as null
  metrics.md    per-session, per-map, loop and timing tables
  session_<s>.png, map_<m>.png unless --no-plots (x right, y down like the image axes)

Exit status 0 on success; 1 with a one-line reason on stderr for bad input (2 for a bad command line).
"""
import argparse
import csv
import json
import math
import os
import sys
from dataclasses import dataclass, field

import numpy as np

NA = None  # a metric that cannot be computed

ODOMETRY_COLUMNS = (("session", int), ("index", int), ("x_m", float), ("y_m", float), ("yaw_rad", float))
TRAJECTORY_COLUMNS = (("session", int), ("index", int), ("map", int), ("x_m", float), ("y_m", float),
                      ("yaw_rad", float))
LOOPS_COLUMNS = (("session_a", int), ("index_a", int), ("session_b", int), ("index_b", int), ("kind", str),
                 ("inliers", float))
LOOP_POSES_COLUMNS = (("session_a", int), ("index_a", int), ("session_b", int), ("index_b", int), ("x_m", float),
                      ("y_m", float), ("yaw_rad", float))
# With loop_poses.csv, an accepted loop is correct when its measured pose of b in a is within
# this fraction of the footprint height (translation) and this angle of the ground truth.
LOOP_POSE_TOL_FRACTION = 0.1
LOOP_POSE_TOL_YAW = math.radians(5.0)
TIMING_COLUMNS = (("stage", str), ("calls", int), ("total_ms", float), ("mean_ms", float), ("max_ms", float))
INPUTS_COLUMNS = (("session", int), ("folder", str), ("frames", int), ("first_stamp_s", float),
                  ("last_stamp_s", float), ("altitude_mean_m", float))
GT_COLUMNS = (("index", int), ("image", str), ("x_m", float), ("y_m", float), ("yaw_rad", float))
FRAMES_COLUMNS = (("index", int), ("image", str), ("stamp_s", float), ("altitude_m", float))
WORLD_GT_COLUMNS = ODOMETRY_COLUMNS
LOOPS_GT_COLUMNS = LOOPS_COLUMNS[:4]
CAMERA_KEYS = ("image_width", "image_height", "fx", "fy", "cx", "cy")

ESTIMATES = ("odometry", "slam")
LOOP_KINDS = ("intra", "inter", "all")


class EvalError(Exception):
    """Bad input: reported as one line on stderr."""


# ---------------------------------------------------------------------------------------------
# SE(2) helpers. A pose is a numpy array (x, y, yaw).

def wrap_angle(a):
    """Wraps angles (scalar or array) to (-pi, pi]."""
    w = np.mod(np.asarray(a, dtype=float) + math.pi, 2.0 * math.pi) - math.pi
    return np.where(w <= -math.pi, w + 2.0 * math.pi, w)


def rotate(xy, yaw):
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([c * xy[0] - s * xy[1], s * xy[0] + c * xy[1]])


def compose(a, b):
    """a ⊕ b: pose b, given in the frame of a, expressed in a's parent frame."""
    xy = a[:2] + rotate(b[:2], a[2])
    return np.array([xy[0], xy[1], float(wrap_angle(a[2] + b[2]))])


def invert(a):
    """⊖a."""
    xy = -rotate(a[:2], -a[2])
    return np.array([xy[0], xy[1], float(wrap_angle(-a[2]))])


def relative(a, b):
    """Pose of b expressed in the frame of pose a (position rotated by -yaw_a)."""
    return compose(invert(a), b)


# ---------------------------------------------------------------------------------------------
# Input.

def read_table(path, columns, required=True):
    """Reads a CSV file with the given (name, type) columns into a list of dicts.

    A missing optional file gives None; a zero-byte file gives no rows. Raises EvalError for a
    missing required file, a header lacking a column, or a value that does not parse."""
    if not os.path.isfile(path):
        if required:
            raise EvalError("%s: file not found" % path)
        return None
    with open(path, newline="") as f:
        lines = list(csv.reader(f))
    lines = [row for row in lines if any(cell.strip() for cell in row)]
    if not lines:
        return []
    header = [name.strip() for name in lines[0]]
    missing = [name for name, _ in columns if name not in header]
    if missing:
        raise EvalError("%s: header '%s' lacks column(s) %s (expected %s)" % (
            path, ",".join(header), ",".join(missing), ",".join(name for name, _ in columns)))
    where = {name: header.index(name) for name, _ in columns}
    rows = []
    for n, line in enumerate(lines[1:], start=2):
        if len(line) != len(header):
            raise EvalError("%s:%d: %d fields, the header has %d" % (path, n, len(line), len(header)))
        row = {}
        for name, kind in columns:
            text = line[where[name]].strip()
            try:
                row[name] = kind(text)
            except ValueError:
                raise EvalError("%s:%d: column %s: cannot read '%s' as %s" % (
                    path, n, name, text, kind.__name__)) from None
        rows.append(row)
    return rows


def read_camera_yaml(path):
    """Reads the flat 'key: value' camera.yaml of a dataset folder."""
    if not os.path.isfile(path):
        raise EvalError("%s: file not found" % path)
    values = {}
    with open(path) as f:
        for n, line in enumerate(f, start=1):
            line = line.split("#", 1)[0].strip()
            if not line or line.startswith("%YAML") or line == "---":
                continue
            key, sep, text = line.partition(":")
            if not sep:
                raise EvalError("%s:%d: expected 'key: value', found '%s'" % (path, n, line))
            values[key.strip()] = text.strip()
    camera = {}
    for key in CAMERA_KEYS:
        if key not in values:
            raise EvalError("%s: missing key '%s'" % (path, key))
        try:
            camera[key] = float(values[key])
        except ValueError:
            raise EvalError("%s: %s: cannot read '%s' as a number" % (path, key, values[key])) from None
    if camera["fy"] <= 0 or camera["image_height"] <= 0:
        raise EvalError("%s: fy and image_height must be positive" % path)
    return camera


def pose_of(row):
    return np.array([row["x_m"], row["y_m"], row["yaw_rad"]])


def keyed_poses(rows, path, key_of):
    """Dict key -> pose from table rows; a key given twice is an error."""
    poses = {}
    for row in rows:
        key = key_of(row)
        if key in poses:
            raise EvalError("%s: %s appears twice" % (path, describe_key(key)))
        poses[key] = pose_of(row)
    return poses


def describe_key(key):
    return "session %d index %d" % key if isinstance(key, tuple) else "index %d" % key


@dataclass
class SessionTruth:
    """One dataset folder's ground truth: gt poses, altitudes and camera, keyed by frame index."""
    directory: str
    poses: dict
    altitude: dict
    camera: dict
    stamps: list = field(default_factory=list)  # frames.csv's stamp_s, in file order

    def footprint_height(self, index):
        """Height in metres of the seabed seen by frame `index`."""
        return self.camera["image_height"] * self.altitude[index] / self.camera["fy"]


@dataclass
class GroundTruth:
    sessions: list
    world: dict = None  # (session, index) -> world pose, or None without world_gt.csv
    loops: list = None  # sorted unordered key pairs from loops_gt.csv, or None

    def relative(self, a, b):
        """Gt pose of key b in the frame of key a, or None when it needs the missing world gt."""
        if a[0] == b[0]:
            poses = self.sessions[a[0]].poses
            return relative(poses[a[1]], poses[b[1]])
        if self.world is None:
            return None
        return relative(self.world_pose(a), self.world_pose(b))

    def world_pose(self, key):
        if key not in self.world:
            raise EvalError("world_gt.csv has no pose for %s" % describe_key(key))
        return self.world[key]

    def distance(self, a, b):
        """Gt distance between the image centres of two keys, or None without world gt."""
        rel = self.relative(a, b)
        return None if rel is None else float(np.hypot(rel[0], rel[1]))


def load_session_truth(directory):
    if not os.path.isdir(directory):
        raise EvalError("%s: ground-truth folder not found" % directory)
    gt_path = os.path.join(directory, "gt.csv")
    frames_path = os.path.join(directory, "frames.csv")
    poses = keyed_poses(read_table(gt_path, GT_COLUMNS), gt_path, lambda r: r["index"])
    frames = read_table(frames_path, FRAMES_COLUMNS)
    altitude = {r["index"]: r["altitude_m"] for r in frames}
    camera = read_camera_yaml(os.path.join(directory, "camera.yaml"))
    return SessionTruth(directory, poses, altitude, camera, [r["stamp_s"] for r in frames])


def unordered(a, b):
    return (a, b) if a <= b else (b, a)


def loop_pairs(rows):
    """Distinct unordered ((session, index), (session, index)) pairs, sorted."""
    pairs = {unordered((r["session_a"], r["index_a"]), (r["session_b"], r["index_b"])) for r in rows}
    return sorted(p for p in pairs if p[0] != p[1])


def load_ground_truth(session_dirs, world_gt=None, loops_gt=None):
    sessions = [load_session_truth(d) for d in session_dirs]
    world = None
    if world_gt is not None:
        world = keyed_poses(read_table(world_gt, WORLD_GT_COLUMNS), world_gt,
                            lambda r: (r["session"], r["index"]))
    loops = None if loops_gt is None else loop_pairs(read_table(loops_gt, LOOPS_GT_COLUMNS))
    return GroundTruth(sessions, world, loops)


@dataclass
class Estimate:
    """Keyframe poses of one estimate, each with the id of the frame it is expressed in."""
    name: str
    poses: dict  # (session, index) -> pose
    frame: dict  # (session, index) -> frame id (session for odometry, map for slam)

    def keys(self, predicate=lambda key: True):
        return sorted(k for k in self.poses if predicate(k))

    def sessions(self):
        return sorted({k[0] for k in self.poses})

    def same_frame(self, a, b):
        return a in self.poses and b in self.poses and self.frame[a] == self.frame[b]

    def relative(self, a, b):
        return relative(self.poses[a], self.poses[b])


@dataclass
class Run:
    odometry: Estimate
    slam: Estimate = None  # None without trajectory.csv
    loops: list = None     # None without loops.csv
    timing: list = None    # None without timing.csv
    loop_poses: dict = None  # (key_a, key_b) -> measured pose of b in a, from loop_poses.csv
    inputs: list = None  # inputs.csv rows: the folders the run was made from (None: not written)

    def estimates(self):
        return [e for e in (self.odometry, self.slam) if e is not None]

    def keyframes(self):
        return set().union(*(e.poses for e in self.estimates()))


def load_run(directory):
    if not os.path.isdir(directory):
        raise EvalError("%s: run directory not found" % directory)
    path = os.path.join(directory, "odometry.csv")
    rows = read_table(path, ODOMETRY_COLUMNS)
    poses = keyed_poses(rows, path, lambda r: (r["session"], r["index"]))
    odometry = Estimate("odometry", poses, {k: k[0] for k in poses})
    path = os.path.join(directory, "trajectory.csv")
    rows = read_table(path, TRAJECTORY_COLUMNS, required=False)
    slam = None
    if rows is not None:
        poses = keyed_poses(rows, path, lambda r: (r["session"], r["index"]))
        slam = Estimate("slam", poses, {(r["session"], r["index"]): r["map"] for r in rows})
    loops = read_table(os.path.join(directory, "loops.csv"), LOOPS_COLUMNS, required=False)
    timing = read_table(os.path.join(directory, "timing.csv"), TIMING_COLUMNS, required=False)
    measured = read_table(os.path.join(directory, "loop_poses.csv"), LOOP_POSES_COLUMNS, required=False)
    loop_poses = None
    if measured is not None:
        loop_poses = {((r["session_a"], r["index_a"]), (r["session_b"], r["index_b"])): pose_of(r) for r in measured}
    inputs = read_table(os.path.join(directory, "inputs.csv"), INPUTS_COLUMNS, required=False)
    return Run(odometry, slam, None if loops is None else loop_pairs(loops), timing, loop_poses, inputs)


def folder_summary(truth):
    """(frames, first stamp, last stamp, mean finite altitude or nan) of a folder's frames.csv."""
    altitudes = [a for a in truth.altitude.values() if math.isfinite(a)]
    stamps = truth.stamps or [0.0]
    return (len(truth.stamps), stamps[0], stamps[-1], float(np.mean(altitudes)) if altitudes else math.nan)


def describe_summary(summary):
    return "%d frames, stamps %.3f..%.3f s, mean altitude %.4f m" % summary


def same_summary(a, b):
    """Equal frame counts; stamps within 1 ms and mean altitudes within 0.1 mm (as written, 6 decimals)."""
    def close(x, y, tol):
        return (math.isnan(x) and math.isnan(y)) or abs(x - y) <= tol
    return a[0] == b[0] and close(a[1], b[1], 1e-3) and close(a[2], b[2], 1e-3) and close(a[3], b[3], 1e-4)


def check_run_against_truth(run, gt):
    """Refuses (EvalError with the reason) a run that is not the run of the folders given: one folder per
    session, every key a frame of its folder's gt.csv, and the folders the run's inputs.csv describes.
    Returns notes for the report."""
    keys = set(run.keyframes())
    for pair in run.loops or []:
        keys.update(pair)
    for session, index in sorted(keys):
        if session < 0 or session >= len(gt.sessions):
            raise EvalError("the run has session %d but only %d ground-truth folder(s) were given: give one folder per "
                            "session of the run, in its order" % (session, len(gt.sessions)))
        truth = gt.sessions[session]
        if index not in truth.poses:
            raise EvalError("%s: no ground truth for frame %d (session %d of the run): not the folder of that "
                            "session?" % (os.path.join(truth.directory, "gt.csv"), index, session))
    empty = [n for n in range(len(gt.sessions)) if n not in {k[0] for k in keys}]
    if empty:
        raise EvalError("%d folder(s) given but the run has no keyframe of session(s) %s (%s): give only the run's "
                        "folders, in its order" % (len(gt.sessions), ", ".join(map(str, empty)),
                                                   ", ".join(gt.sessions[n].directory for n in empty)))
    if run.inputs is None:
        return ["the run has no inputs.csv: its folders were checked by session count and frame indexes only"]
    for row in run.inputs:
        n = row["session"]
        if n < 0 or n >= len(gt.sessions):
            raise EvalError("the run was made from folder %s as session %d (inputs.csv) but only %d folder(s) were "
                            "given" % (row["folder"], n, len(gt.sessions)))
        made = (row["frames"], row["first_stamp_s"], row["last_stamp_s"], row["altitude_mean_m"])
        given = folder_summary(gt.sessions[n])
        if not same_summary(made, given):
            raise EvalError("session %d of the run was made from %s (%s), but %s has %s: not the same folder (give "
                            "the run's folders, in its order)" % (n, row["folder"], describe_summary(made),
                                                                  gt.sessions[n].directory, describe_summary(given)))
    return []


# ---------------------------------------------------------------------------------------------
# Ground truth in the estimate's frames.

def gt_in_estimate_frames(estimate, gt):
    """Gt pose of every keyframe in the frame its estimate is expressed in.

    Returns (poses, unavailable): poses maps key -> gt pose for the frames that can be
    expressed; unavailable lists the frame ids that need world_gt.csv, which is missing."""
    groups = {}
    for key in estimate.keys():
        groups.setdefault(estimate.frame[key], []).append(key)
    poses, unavailable = {}, []
    for frame_id, keys in sorted(groups.items()):
        anchor = keys[0]  # lowest session, then lowest index: the frame's origin
        if len({k[0] for k in keys}) == 1:
            source = {k: gt.sessions[k[0]].poses[k[1]] for k in keys}
        elif gt.world is not None:
            source = {k: gt.world_pose(k) for k in keys}
        else:
            unavailable.append(frame_id)
            continue
        for key in keys:
            poses[key] = relative(source[anchor], source[key])
    return poses, unavailable


# ---------------------------------------------------------------------------------------------
# Metrics.

def ate_rmse(est_xy, gt_xy):
    """RMSE of position differences, no alignment."""
    d = np.asarray(est_xy, float) - np.asarray(gt_xy, float)
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))


def align_se2(est_xy, gt_xy):
    """Best rigid 2-D transform (yaw, t) minimising sum |R(yaw) est + t - gt|^2 (no scale)."""
    est_xy, gt_xy = np.asarray(est_xy, float), np.asarray(gt_xy, float)
    ce, cg = est_xy.mean(axis=0), gt_xy.mean(axis=0)
    e, g = est_xy - ce, gt_xy - cg
    yaw = math.atan2(np.sum(e[:, 0] * g[:, 1] - e[:, 1] * g[:, 0]), np.sum(e[:, 0] * g[:, 0] + e[:, 1] * g[:, 1]))
    return yaw, cg - rotate(ce, yaw)


def ate_aligned_rmse(est_xy, gt_xy):
    """ATE RMSE after the best SE(2) alignment of the estimate onto the gt."""
    yaw, t = align_se2(est_xy, gt_xy)
    c, s = math.cos(yaw), math.sin(yaw)
    aligned = np.asarray(est_xy, float) @ np.array([[c, s], [-s, c]]) + t
    return ate_rmse(aligned, gt_xy)


def path_length(gt_xy):
    """Sum of distances between consecutive positions."""
    gt_xy = np.asarray(gt_xy, float)
    return float(np.sum(np.hypot(*np.diff(gt_xy, axis=0).T))) if len(gt_xy) > 1 else 0.0


def end_drift_pct(est_xy, gt_xy):
    """Distance between the final estimated and gt positions in % of the gt path length."""
    length = path_length(gt_xy)
    if length <= 0.0:
        return NA
    return float(100.0 * np.hypot(*(np.asarray(est_xy[-1]) - np.asarray(gt_xy[-1]))) / length)


def relative_errors(estimate, gt, pairs):
    """For each pair (i, j) with a gt relative pose: translation error |t_gt(j|i) - t_est(j|i)|
    and yaw error wrapped to (-pi, pi]. Returns two arrays."""
    trans, rot = [], []
    for a, b in pairs:
        truth = gt.relative(a, b)
        if truth is None:
            continue
        est = estimate.relative(a, b)
        trans.append(float(np.hypot(*(truth[:2] - est[:2]))))
        rot.append(float(wrap_angle(est[2] - truth[2])))
    return np.array(trans), np.array(rot)


def rms(values):
    return float(np.sqrt(np.mean(np.square(values)))) if len(values) else NA


def rpe(estimate, gt, keys):
    """RPE between consecutive keyframes (in `keys` order) that share a frame."""
    pairs = [(a, b) for a, b in zip(keys, keys[1:]) if estimate.same_frame(a, b)]
    trans, rot = relative_errors(estimate, gt, pairs)
    return {"rpe_trans_rmse_m": rms(trans),
            "rpe_rot_rmse_deg": NA if not len(rot) else math.degrees(rms(rot))}


def e_k(estimate, gt, pairs):
    """The paper's e_k (35) over the pairs usable in the estimate: (mean error, pairs used)."""
    usable = [p for p in pairs if estimate.same_frame(*p)]
    trans, _ = relative_errors(estimate, gt, usable)
    return (float(np.mean(trans)) if len(trans) else NA), len(trans)


def absolute_metrics(estimate, gt_poses, keys, with_drift=True):
    """ATE, aligned ATE and (optionally) path length and end drift over `keys`."""
    names = ["ate_rmse_m", "ate_aligned_rmse_m"] + (["path_length_m", "end_drift_pct"] if with_drift else [])
    if not keys or any(k not in gt_poses for k in keys):
        return dict.fromkeys(names, NA)
    est_xy = np.array([estimate.poses[k][:2] for k in keys])
    gt_xy = np.array([gt_poses[k][:2] for k in keys])
    out = {"ate_rmse_m": ate_rmse(est_xy, gt_xy), "ate_aligned_rmse_m": ate_aligned_rmse(est_xy, gt_xy)}
    if with_drift:
        out.update(path_length_m=path_length(gt_xy), end_drift_pct=end_drift_pct(est_xy, gt_xy))
    return out


def ek_metrics(estimate, gt, pairs, kind):
    value, used = e_k(estimate, gt, pairs)
    return {"ek_%s_m" % kind: value, "ek_%s_pairs" % kind: used}


def session_metrics(estimate, gt, gt_poses, session):
    keys = estimate.keys(lambda k: k[0] == session)
    out = {"n_keyframes": len(keys)}
    out.update(absolute_metrics(estimate, gt_poses, keys))
    out.update(rpe(estimate, gt, keys))
    gt_pairs = gt.loops or []
    out.update(ek_metrics(estimate, gt, [p for p in gt_pairs if p[0][0] == p[1][0] == session], "intra"))
    if estimate.name == "slam":
        inter = [p for p in gt_pairs if p[0][0] != p[1][0] and session in (p[0][0], p[1][0])]
        out.update(ek_metrics(estimate, gt, inter, "inter"))
    return out


def map_metrics(estimate, gt, gt_poses, map_id):
    keys = estimate.keys(lambda k: estimate.frame[k] == map_id)
    out = {"n_sessions": len({k[0] for k in keys}), "n_keyframes": len(keys)}
    out.update(absolute_metrics(estimate, gt_poses, keys, with_drift=False))
    inside = [p for p in (gt.loops or []) if estimate.frame.get(p[0]) == map_id]
    out.update(ek_metrics(estimate, gt, [p for p in inside if p[0][0] == p[1][0]], "intra"))
    out.update(ek_metrics(estimate, gt, [p for p in inside if p[0][0] != p[1][0]], "inter"))
    return out


def loop_kind(pair):
    return "intra" if pair[0][0] == pair[1][0] else "inter"


def true_loop_distance(gt, pair, fixed=None):
    """Distance below which a loop is correct: `fixed`, else the mean footprint height of the
    frames with a valid (finite, positive) altitude; None when neither has one (n/a)."""
    if fixed is not None:
        return fixed
    heights = []
    for session, index in pair:
        truth = gt.sessions[session]
        if index not in truth.altitude:
            raise EvalError("%s: no altitude for frame %d" % (os.path.join(truth.directory, "frames.csv"), index))
        h = truth.footprint_height(index)
        if math.isfinite(h) and h > 0:
            heights.append(h)
    return float(np.mean(heights)) if heights else None


def measured_pose(loop_poses, pair):
    """The measured pose of pair[1] in pair[0] from loop_poses.csv (either order), or None."""
    if not loop_poses:
        return None
    if pair in loop_poses:
        return loop_poses[pair]
    reverse = (pair[1], pair[0])
    return invert(loop_poses[reverse]) if reverse in loop_poses else None


def judge_loops(gt, accepted, fixed_dist=None, loop_poses=None):
    """Dict pair -> True (correct), False (wrong) or None (no gt).

    With the loop's measured pose (loop_poses.csv) a loop is correct when that pose agrees with
    the ground-truth relative pose: translation within LOOP_POSE_TOL_FRACTION of the footprint
    height and yaw within LOOP_POSE_TOL_YAW. Without it, when the two image centres are closer
    than the true-loop distance (the images overlap)."""
    verdict = {}
    for pair in accepted:
        rel = gt.relative(*pair)
        if rel is None:
            verdict[pair] = None
            continue
        limit = true_loop_distance(gt, pair, fixed_dist)
        z = measured_pose(loop_poses, pair)
        if limit is None:
            verdict[pair] = None
        elif z is None:
            verdict[pair] = float(np.hypot(rel[0], rel[1])) < limit
        else:
            verdict[pair] = bool(np.hypot(z[0] - rel[0], z[1] - rel[1]) < LOOP_POSE_TOL_FRACTION * limit
                                 and abs(wrap_angle(z[2] - rel[2])) < LOOP_POSE_TOL_YAW)
    return verdict


def of_kind(pairs, kind):
    return [p for p in pairs if kind == "all" or loop_kind(p) == kind]


def loop_metrics(run, gt, verdict):
    """Precision and recall per kind (intra, inter, all)."""
    keyframes = run.keyframes()
    out = {}
    for kind in LOOP_KINDS:
        m = dict.fromkeys(("accepted", "correct", "precision", "gt_pairs", "gt_pairs_keyframes", "found",
                           "recall"), NA)
        if run.loops is not None:
            accepted = of_kind(run.loops, kind)
            judged = [verdict[p] for p in accepted]
            m["accepted"] = len(accepted)
            m["correct"] = NA if None in judged else sum(judged)
            m["precision"] = NA if None in judged or not judged else sum(judged) / len(judged)
        if gt.loops is not None:
            gt_pairs = of_kind(gt.loops, kind)
            reachable = [p for p in gt_pairs if p[0] in keyframes and p[1] in keyframes]
            m["gt_pairs"], m["gt_pairs_keyframes"] = len(gt_pairs), len(reachable)
            if run.loops is not None:
                m["found"] = len(set(reachable) & set(run.loops))
                m["recall"] = m["found"] / len(reachable) if reachable else NA
        out[kind] = m
    return out


# ---------------------------------------------------------------------------------------------
# Evaluation: everything as long-format rows.

@dataclass
class Evaluation:
    rows: list = field(default_factory=list)   # (scope, id, estimate, metric, value)
    notes: list = field(default_factory=list)
    gt_poses: dict = field(default_factory=dict)  # estimate name -> key -> gt pose in its frame
    verdict: dict = field(default_factory=dict)   # accepted loop pair -> True / False / None

    def add(self, scope, ident, estimate, metrics):
        self.rows += [(scope, str(ident), estimate, name, value) for name, value in metrics.items()]

    def nested(self):
        out = {}
        for scope, ident, estimate, metric, value in self.rows:
            out.setdefault(scope, {}).setdefault(ident, {}).setdefault(estimate, {})[metric] = value
        return out


def evaluate(run, gt, loop_true_dist=None):
    ev = Evaluation()
    for estimate in run.estimates():
        poses, unavailable = gt_in_estimate_frames(estimate, gt)
        ev.gt_poses[estimate.name] = poses
        for frame_id in unavailable:
            ev.notes.append("map %s holds several sessions: its absolute metrics need world_gt.csv" % frame_id)
    if gt.world is None and len(run.odometry.sessions()) > 1:
        ev.notes.append("no world_gt.csv: inter-session e_k and inter-session loop precision are n/a")
    if gt.loops is None:
        ev.notes.append("no loops_gt.csv: e_k and loop recall are n/a")
    if run.slam is None:
        ev.notes.append("no trajectory.csv: slam metrics are absent")
    if run.loops is None:
        ev.notes.append("no loops.csv: loop precision and recall are n/a")
    sessions = sorted(set().union(*(e.sessions() for e in run.estimates())))
    for session in sessions:
        for estimate in run.estimates():
            if session in estimate.sessions():
                ev.add("session", session, estimate.name,
                       session_metrics(estimate, gt, ev.gt_poses[estimate.name], session))
    if run.slam is not None:
        for map_id in sorted(set(run.slam.frame.values())):
            ev.add("map", map_id, "slam", map_metrics(run.slam, gt, ev.gt_poses["slam"], map_id))
    ev.verdict = judge_loops(gt, run.loops or [], loop_true_dist, run.loop_poses)
    for kind, metrics in loop_metrics(run, gt, ev.verdict).items():
        ev.add("loops", kind, "loops", metrics)
    for row in run.timing or []:
        ev.add("timing", row["stage"], "timing", {k: row[k] for k, _ in TIMING_COLUMNS[1:]})
    return ev


# ---------------------------------------------------------------------------------------------
# Report.

def csv_value(value):
    if value is None:
        return "n/a"
    return str(value) if isinstance(value, int) else "%.9g" % value


def md_value(value, digits=3):
    if value is None:
        return "n/a"
    return str(value) if isinstance(value, int) else "%.*f" % (digits, value)


def md_table(headers, rows):
    lines = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def with_pairs(metrics, kind):
    name = "ek_%s_m" % kind
    if name not in metrics:
        return "–"
    return "%s (%d)" % (md_value(metrics[name]), metrics["ek_%s_pairs" % kind])


SESSION_COLUMNS = (("keyframes", "n_keyframes"), ("path (m)", "path_length_m"), ("ATE (m)", "ate_rmse_m"),
                   ("aligned ATE (m)", "ate_aligned_rmse_m"), ("end drift (%)", "end_drift_pct"),
                   ("RPE trans (m)", "rpe_trans_rmse_m"), ("RPE rot (deg)", "rpe_rot_rmse_deg"))
MAP_COLUMNS = (("sessions", "n_sessions"), ("keyframes", "n_keyframes"), ("ATE (m)", "ate_rmse_m"),
               ("aligned ATE (m)", "ate_aligned_rmse_m"))
LOOP_COLUMNS = ("accepted", "correct", "precision", "gt_pairs", "gt_pairs_keyframes", "found", "recall")
EK_HEADERS = ("e_k intra (m) (pairs)", "e_k inter (m) (pairs)")


def markdown(ev):
    data = ev.nested()
    parts = ["# SLAM evaluation"]

    def metric_cells(metrics, columns):
        return [md_value(metrics[name]) for _, name in columns]

    rows = [[sid, est] + metric_cells(m, SESSION_COLUMNS) + [with_pairs(m, "intra"), with_pairs(m, "inter")]
            for sid, by_est in data.get("session", {}).items() for est, m in by_est.items()]
    parts += ["## Sessions", md_table(["session", "estimate"] + [h for h, _ in SESSION_COLUMNS] + list(EK_HEADERS),
                                      rows)]
    rows = [[mid] + metric_cells(m["slam"], MAP_COLUMNS) + [with_pairs(m["slam"], "intra"),
                                                            with_pairs(m["slam"], "inter")]
            for mid, m in data.get("map", {}).items()]
    if rows:
        parts += ["## Maps (slam)", md_table(["map"] + [h for h, _ in MAP_COLUMNS] + list(EK_HEADERS), rows)]
    rows = [[kind] + [md_value(m["loops"][c]) for c in LOOP_COLUMNS] for kind, m in data.get("loops", {}).items()]
    parts += ["## Loops", md_table(["pairs"] + list(LOOP_COLUMNS), rows)]
    if "timing" in data:
        rows = [[stage] + [md_value(v, 2) for v in m["timing"].values()] for stage, m in data["timing"].items()]
        parts += ["## Timing", md_table(["stage"] + [c for c, _ in TIMING_COLUMNS[1:]], rows)]
    if ev.notes:
        parts += ["## Notes", "\n".join("- " + n for n in ev.notes)]
    return "\n\n".join(parts) + "\n"


def write_report(ev, report_dir):
    os.makedirs(report_dir, exist_ok=True)
    with open(os.path.join(report_dir, "metrics.csv"), "w", newline="") as f:
        out = csv.writer(f, lineterminator="\n")
        out.writerow(("scope", "id", "estimate", "metric", "value"))
        out.writerows(row[:4] + (csv_value(row[4]),) for row in ev.rows)
    with open(os.path.join(report_dir, "metrics.json"), "w") as f:
        json.dump(ev.nested(), f, indent=2)
        f.write("\n")
    text = markdown(ev)
    with open(os.path.join(report_dir, "metrics.md"), "w") as f:
        f.write(text)
    return text


# ---------------------------------------------------------------------------------------------
# Plots.

def session_frame_truth(gt, keys):
    """Gt poses of one session's keys in the frame of its first key."""
    poses = gt.sessions[keys[0][0]].poses
    return {k: relative(poses[keys[0][1]], poses[k[1]]) for k in keys}


def slam_in_session_frame(ev, slam, session_gt, keys):
    """SLAM poses of one session moved from their map frame into the session frame through the
    gt transform between the two frames (no fitting); keys whose map lacks gt are dropped."""
    gt_map = ev.gt_poses["slam"]
    to_session = {}  # map id -> map frame expressed in the session frame
    for key in keys:
        if key in gt_map and slam.frame[key] not in to_session:
            to_session[slam.frame[key]] = compose(session_gt[key], invert(gt_map[key]))
    return {k: compose(to_session[slam.frame[k]], slam.poses[k]) for k in keys if slam.frame[k] in to_session}


def draw_path(ax, poses, keys, label, style, marker_start=True):
    keys = [k for k in keys if k in poses]
    if not keys:
        return
    xy = np.array([poses[k][:2] for k in keys])
    line, = ax.plot(xy[:, 0], xy[:, 1], style, label=label, linewidth=1.2, markersize=2.5)
    if marker_start:
        ax.plot(xy[0, 0], xy[0, 1], "o", color=line.get_color(), markersize=7, markerfacecolor="none")


def finish_axes(ax, fig, title, path):
    ax.set_title(title)
    ax.set_xlabel("x (m, image u axis)")
    ax.set_ylabel("y (m, image v axis)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.invert_yaxis()
    ax.grid(True, linewidth=0.3)
    ax.legend(fontsize=7, loc="best")
    fig.savefig(path, dpi=110, bbox_inches="tight")


def plot_session(plt, ev, run, gt, session, path):
    keys = sorted(k for k in run.keyframes() if k[0] == session)
    truth = session_frame_truth(gt, keys)
    fig, ax = plt.subplots(figsize=(7, 6))
    draw_path(ax, truth, keys, "ground truth", "k.-")
    draw_path(ax, run.odometry.poses, keys, "odometry", ".-")
    if run.slam is not None:
        draw_path(ax, slam_in_session_frame(ev, run.slam, truth, run.slam.keys(lambda k: k[0] == session)),
                  keys, "SLAM", ".-")
    finish_axes(ax, fig, "session %d (session frame; o = start)" % session, path)
    plt.close(fig)


LOOP_COLOURS = {True: "tab:green", False: "tab:red", None: "tab:gray"}


def plot_map(plt, ev, run, map_id, path):
    slam = run.slam
    keys = slam.keys(lambda k: slam.frame[k] == map_id)
    gt_map = ev.gt_poses["slam"]
    fig, ax = plt.subplots(figsize=(7, 6))
    for pair, ok in ev.verdict.items():
        if all(slam.frame.get(k) == map_id for k in pair):
            xy = np.array([slam.poses[k][:2] for k in pair])
            ax.plot(xy[:, 0], xy[:, 1], "-", color=LOOP_COLOURS[ok], linewidth=0.7, alpha=0.9, zorder=3)
    for n, session in enumerate(sorted({k[0] for k in keys})):
        skeys = [k for k in keys if k[0] == session]
        draw_path(ax, gt_map, skeys, None if n else "ground truth", "k--")
        draw_path(ax, slam.poses, skeys, "SLAM s%d" % session, ".-")
    for ok, name in ((True, "correct loop"), (False, "wrong loop")):
        ax.plot([], [], "-", color=LOOP_COLOURS[ok], linewidth=0.8, label=name)
    finish_axes(ax, fig, "map %d (map frame; o = start)" % map_id, path)
    plt.close(fig)


def write_plots(ev, run, gt, report_dir):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    written = []
    for session in sorted({k[0] for k in run.keyframes()}):
        written.append(os.path.join(report_dir, "session_%d.png" % session))
        plot_session(plt, ev, run, gt, session, written[-1])
    if run.slam is not None:
        for map_id in sorted(set(run.slam.frame.values())):
            written.append(os.path.join(report_dir, "map_%d.png" % map_id))
            plot_map(plt, ev, run, map_id, written[-1])
    return written


# ---------------------------------------------------------------------------------------------
# Command line.

class OneLineParser(argparse.ArgumentParser):
    """argparse that reports a usage error as one line."""

    def error(self, message):
        self.exit(2, "%s: error: %s (see --help)\n" % (self.prog, message))


def positive_float(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError("'%s' is not a number" % text) from None
    if not value > 0:
        raise argparse.ArgumentTypeError("must be positive, got %s" % text)
    return value


def parse_args(argv):
    doc = __doc__.split("\n\n", 1)
    parser = OneLineParser(
        prog="evaluate.py", description=doc[0], epilog=doc[1], formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", required=True, metavar="OUT_DIR", help="output directory of offline_slam")
    truth = parser.add_mutually_exclusive_group(required=True)
    truth.add_argument("--session", action="append", metavar="DIR",
                       help="dataset folder of run session 0, 1, ... (repeat, in the run's order)")
    truth.add_argument("--mission", metavar="DIR",
                       help="folder of session subfolders (those holding frames.csv, sorted by name), "
                            "with world_gt.csv and loops_gt.csv taken from it when present")
    parser.add_argument("--world-gt", metavar="FILE", help="world_gt.csv: all sessions in one world frame")
    parser.add_argument("--loops-gt", metavar="FILE", help="loops_gt.csv: the revisits to find")
    parser.add_argument("--report", required=True, metavar="REPORT_DIR", help="where to write the report")
    parser.add_argument("--no-plots", action="store_true", help="do not write PNG plots")
    parser.add_argument("--loop-true-dist", type=positive_float, metavar="M",
                        help="gt distance (m) below which an accepted loop is correct "
                             "(default: the image footprint height at the frames' mean altitude)")
    return parser.parse_args(argv)


def resolve_truth_inputs(args):
    """(session dirs, world_gt path or None, loops_gt path or None) from the command line."""
    world, loops = args.world_gt, args.loops_gt
    for path in (world, loops):
        if path is not None and not os.path.isfile(path):
            raise EvalError("%s: file not found" % path)
    if args.session:
        return args.session, world, loops
    mission = args.mission
    if not os.path.isdir(mission):
        raise EvalError("%s: mission folder not found" % mission)
    sessions = [os.path.join(mission, name) for name in sorted(os.listdir(mission))
                if os.path.isfile(os.path.join(mission, name, "frames.csv"))]
    if not sessions:
        raise EvalError("%s: no session subfolder (one holding frames.csv)" % mission)
    return sessions, mission_file(mission, "world_gt.csv", world), mission_file(mission, "loops_gt.csv", loops)


def mission_file(mission, name, override):
    """`override` if given, else MISSION/name when it exists, else None."""
    if override is not None:
        return override
    candidate = os.path.join(mission, name)
    return candidate if os.path.isfile(candidate) else None


def main(argv=None):
    try:
        args = parse_args(sys.argv[1:] if argv is None else argv)
    except SystemExit as e:  # --help or a usage error, already printed
        return e.code
    try:
        session_dirs, world_gt, loops_gt = resolve_truth_inputs(args)
        gt = load_ground_truth(session_dirs, world_gt, loops_gt)
        run = load_run(args.run)
        notes = check_run_against_truth(run, gt)
        ev = evaluate(run, gt, args.loop_true_dist)
        ev.notes += notes
        text = write_report(ev, args.report)
        if not args.no_plots:
            write_plots(ev, run, gt, args.report)
    except (EvalError, OSError) as e:
        print("evaluate.py: error: %s" % e, file=sys.stderr)
        return 1
    print(text, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
