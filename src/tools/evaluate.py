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
  A folder that a tracking loss split into pieces (the run's pieces.csv: session,piece,
  store_session,first_index,last_index,keyframes,map) is scored per piece, in rows "S.P" (piece P
  of session S), each piece's odometry in its own frame (it restarts at the origin) and a note
  says so; without pieces.csv or a split, one row per session as below.
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

Steps between consecutive keyframes (per session, both estimates; kinks)
  max_step_m           the largest distance between consecutive keyframes (the pairs of RPE).
  max_step_gt_m        the same in the ground truth, over the same pairs.
  max_step_excess_m    max_step_m - max_step_gt_m: a kink (a step the vehicle did not make)
                       shows as a positive excess.
  max_step_err_m       the largest |t_gt(j|i) - t_est(j|i)| over the same pairs (the worst RPE
                       term); max_step_err_index: the frame index of that step's second keyframe.
  max_turn_deg, max_turn_gt_deg, max_turn_err_deg: the same for |yaw(j|i)|, in degrees.

Metrics (per map, slam)
  n_sessions (the pieces of a split folder counted apart), n_keyframes, ate_rmse_m,
  ate_aligned_rmse_m over all keyframes of the map,
  ek_intra_m / ek_inter_m (+ _pairs) over the loops_gt.csv pairs inside the map.

Mosaic consistency (per map, slam; with --mosaic-score, which reads the keyframes' images)
  mosaic_disagreement     the photometric disagreement of the map's mosaic: for every pair of
                          keyframes whose images overlap in the ground truth, a 24 x 18 grid of
                          pixels of the first is put on the seabed by the estimated poses and
                          altitudes (pixel (u, v) at pose (+) ((u - cx) h / fx, (v - cy) h / fy))
                          and looked up in the second; the mean absolute difference of the two
                          images' intensities there, each image z-scored (exposure and contrast
                          normalised), over all such points of all pairs. 0 = the images agree.
  mosaic_disagreement_gt  the same with the ground-truth poses (the frames' noise, light and
                          haze leave it above 0: the best a map can do).
  mosaic_ratio            mosaic_disagreement / mosaic_disagreement_gt: 1 = as consistent as the
                          ground truth; mosaic_pairs = pairs used.
  --mosaic-png DIR        (implies --mosaic-score) per map, the mosaic drawn from the estimated
                          poses (DIR/map_<m>_slam.png) and from the ground truth's
                          (DIR/map_<m>_gt.png), side by side material for a person: one raster
                          for both (the same extent, covering both, and resolution: the median
                          keyframe's ground pixel, coarser when the ground truth's extent would
                          pass 600 px; the grid in multiples of it, so the ground truth's mosaic
                          does not move with the estimate), every raster pixel put on the seabed
                          and looked up in each keyframe seeing it with the projection above
                          (nearest pixel of the frame shrunk to the raster's resolution), the
                          keyframes seeing it averaged (a misplaced keyframe shows as a ghost),
                          each frame's colour channels scaled to the map's mean; RGBA PNG
                          (transparent where nothing is drawn) and a world file (.pgw: the z-up
                          map frame, as export_survey writes it).

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
  found_near           gt_pairs found by an accepted loop that is not judged wrong and joins
                       keyframes within NEAR_FRAMES (1) frame index of each of the pair's frames,
                       in the same sessions (either order): a pair whose frames did not both
                       become keyframes can still be found through their neighbours.
  recall_all           found_near / gt_pairs: the recall over all ground-truth pairs.

Similarity alignment (per session and map, both estimates)
  ate_sim_rmse_m       ATE after the best 2-D similarity (rotation, translation and scale)
                       alignment (Umeyama): for reconstructions without metric scale (SfM).
  sim_scale            that alignment's scale (estimate -> ground truth).

Timing: timing.csv copied as rows (scope timing, id = stage).

The run must be the run of the folders given, else it is refused with the reason: one folder per
session of the run (no folder without keyframes, no session without a folder), every keyframe a
frame of its folder's gt.csv, and, when the run has inputs.csv (offline_slam and record_run.py
--session-dir write it: session,folder,frames,first_stamp_s,last_stamp_s,altitude_mean_m; or
--inputs FILE), each session's folder with the same number of frames, first and last stamp_s and
mean altitude. A session read from a bag (its inputs.csv `folder` a file, or named *.bag) numbers
its frames by position in the bag and stamps them with the header stamps: it is scored against its
dataset folder given like any other, image k of the bag as the folder's frame k in stamp order,
when the bag has the folder's number of frames over the same span of time (first to last stamp,
within 1 ms; the stamps may sit any constant offset after the folder's, e.g. folder_to_bag's
--start-time) at the same mean altitude; else it is refused.

Outputs
  metrics.csv   long format: scope,id,estimate,metric,value (value n/a when not computable)
  metrics.json  {scope: {id: {estimate: {metric: value}}}}, n/a as null
  metrics.md    per-session, per-map, loop and timing tables
  session_<s>.png, map_<m>.png unless --no-plots (x right, y down like the image axes): each
                session in its own colour, ground truth dotted, the odometry dashed under the
                SLAM line (from where the SLAM puts the session's first keyframe), the accepted
                loops green (correct) / red (wrong) / grey (not judged), the join links of
                links.csv thick black; a map more than 5 times longer than wide gets a second,
                stretched view below the equal-axes one
  report.html   with --html: one self-contained file (no external link) with the figures, the
                tables, the run's inputs.csv and config.yaml, and the command
  Every file is written by atomic_file.py (beside this file): a temporary in the same folder,
  created without following a link, fsync'd and renamed into place; a link planted at a report
  name is replaced, never written through.

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

# atomic_file.py sits beside this file (in the source tree and where the tools are installed).
sys.path.insert(0, os.path.dirname(os.path.realpath(__file__)))
from atomic_file import AtomicFile, write_atomically  # noqa: E402

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
LINKS_COLUMNS = (("map", int), ("previous_session", int), ("current_session", int), ("loops", int), ("x_m", float),
                 ("y_m", float), ("yaw_rad", float))
PIECES_COLUMNS = (("session", int), ("piece", int), ("store_session", int), ("first_index", int),
                  ("last_index", int), ("keyframes", int), ("map", int))
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

def read_table(path, columns, required=True, optional=()):
    """Reads a CSV file with the given (name, type) columns into a list of dicts; the `optional`
    (name, type) columns too when the header has them (else their value is None).

    A missing optional file gives None; a header alone gives no rows. Raises EvalError for a
    missing required file, a file without even a header (every tool writes one: a zero-byte file
    is an output cut off before its first line, not an empty result), a header lacking a column,
    or a value that does not parse."""
    if not os.path.isfile(path):
        if required:
            raise EvalError("%s: file not found" % path)
        return None
    with open(path, newline="", encoding="utf-8-sig") as f:  # -sig: a spreadsheet's byte-order mark
        lines = list(csv.reader(f))
    lines = [row for row in lines if any(cell.strip() for cell in row)]
    if not lines:
        raise EvalError("%s: empty file, not even a header (an output cut off before its first line?)" % path)
    header = [name.strip() for name in lines[0]]
    missing = [name for name, _ in columns if name not in header]
    if missing:
        raise EvalError("%s: header '%s' lacks column(s) %s (expected %s)" % (
            path, ",".join(header), ",".join(missing), ",".join(name for name, _ in columns)))
    columns = tuple(columns) + tuple(c for c in optional if c[0] in header)
    where = {name: header.index(name) for name, _ in columns}
    rows = []
    for n, line in enumerate(lines[1:], start=2):
        if len(line) != len(header):
            raise EvalError("%s:%d: %d fields, the header has %d" % (path, n, len(line), len(header)))
        row = dict.fromkeys((name for name, _ in optional), None)
        for name, kind in columns:
            text = line[where[name]].strip()
            try:
                row[name] = kind(text)
            except ValueError:
                raise EvalError("%s:%d: column %s: cannot read '%s' as %s" % (
                    path, n, name, text, kind.__name__)) from None
        rows.append(row)
    return rows


def _CameraYamlLoader():
    """PyYAML's safe loader reading plain numbers as YAML 1.2 and yaml-cpp do: 1e3 is a number (YAML 1.1
    wants a dot, 1.0e+3). Quoted scalars stay text."""
    import re
    import yaml

    class Loader(yaml.SafeLoader):
        pass
    Loader.add_implicit_resolver("tag:yaml.org,2002:float", re.compile(
        r"^[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][-+]?[0-9]+)?$"), list("-+0123456789."))
    return Loader


def read_camera_yaml(path):
    """Reads a dataset folder's camera.yaml in either layout core::readCameraYaml reads
    (doc/dataset_format.md): the six keys image_width, image_height, fx, fy, cx, cy, or a ROS
    calibration YAML (camera_calibration_parsers' format, recognised by its camera_matrix key; K
    gives fx, fy, cx, cy). Only K and the image size are used here: the poses are the image
    centres', and the mosaic score projects with K (a lens's distortion is not undone there).
    Returns {key: float} for the six keys; EvalError naming the file and the key otherwise."""
    import yaml
    if not os.path.isfile(path):
        raise EvalError("%s: file not found" % path)
    with open(path, encoding="utf-8-sig") as f:
        text = f.read()
    try:
        root = yaml.load(text, Loader=_CameraYamlLoader())
    except yaml.YAMLError as e:
        where = getattr(e, "problem_mark", None)
        raise EvalError("%s%s: not YAML (%s)" % (path, ":%d" % (where.line + 1) if where else "",
                                                   getattr(e, "problem", None) or e)) from None
    if not isinstance(root, dict):
        raise EvalError("%s: expected 'key: value' lines (image_width, image_height, fx, fy, cx, cy) or a ROS "
                        "calibration YAML" % path)

    def number(value, key):
        # A quoted number is text, as the C++ readers say (bool is an int in Python: refused too).
        if isinstance(value, str):
            try:
                float(value)
            except ValueError:
                pass
            else:
                raise EvalError("%s: %s: '%s' is quoted text, not a number (write it without quotes)" % (
                    path, key, value))
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise EvalError("%s: %s: cannot read %r as a number" % (path, key, value))
        return float(value)

    def required(key):
        if key not in root:
            raise EvalError("%s: missing key '%s'" % (path, key))
        return root[key]

    def matrix(key, rows, cols):
        m = required(key)
        data = m.get("data") if isinstance(m, dict) else None
        if not isinstance(data, list) or m.get("rows") != rows or m.get("cols") != cols or len(data) != rows * cols:
            raise EvalError("%s: %s must be {rows: %d, cols: %d, data: [%d numbers]}" % (
                path, key, rows, cols, rows * cols))
        return [number(v, "%s.data[%d]" % (key, i)) for i, v in enumerate(data)]

    if "camera_matrix" in root:
        k = matrix("camera_matrix", 3, 3)
        camera = {"image_width": number(required("image_width"), "image_width"),
                  "image_height": number(required("image_height"), "image_height"),
                  "fx": k[0], "fy": k[4], "cx": k[2], "cy": k[5]}
        model = required("distortion_model")
        counts = {"plumb_bob": (4, 5), "rational_polynomial": (8,)}
        if model not in counts:
            raise EvalError("%s: distortion_model '%s' is not supported (plumb_bob or rational_polynomial)" % (
                path, model))
        d = required("distortion_coefficients")
        n = d.get("cols") if isinstance(d, dict) else None
        if n not in counts[model]:
            raise EvalError("%s: distortion_coefficients: %s takes %s coefficients, found %s" % (
                path, model, " or ".join(map(str, counts[model])), n))
        matrix("distortion_coefficients", 1, n)
        if "rectification_matrix" in root:
            matrix("rectification_matrix", 3, 3)
        if "projection_matrix" in root:
            matrix("projection_matrix", 3, 4)
    else:
        camera = {key: number(required(key), key) for key in CAMERA_KEYS}
    for key in ("image_width", "image_height"):
        if not (1 <= camera[key] <= 1e6 and camera[key] == int(camera[key])):
            raise EvalError("%s: %s must be a whole number of pixels in [1, 1000000]" % (path, key))
    if not (camera["fx"] > 0 and camera["fy"] > 0):
        raise EvalError("%s: fx and fy must be positive" % path)
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
    images: dict = field(default_factory=dict)  # index -> image file name (frames.csv)
    indexes: list = field(default_factory=list)  # frames.csv's index, in file order

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
    return SessionTruth(directory, poses, altitude, camera, [r["stamp_s"] for r in frames],
                        {r["index"]: r["image"] for r in frames}, [r["index"] for r in frames])


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
    links: list = None   # links.csv rows: the join links (None: not written)
    pieces: dict = None  # key -> "S.P" for the keyframes of folders split by tracking loss (pieces.csv)

    def units(self, session):
        """The scored units of a session: [(id, keys)], one per piece when tracking loss split it."""
        keys = sorted(k for k in self.keyframes() if k[0] == session)
        labels = sorted({self.pieces[k] for k in keys if k in (self.pieces or {})}, key=lambda p: int(p.split(".")[1]))
        if not labels:
            return [(session, keys)]
        return [(label, [k for k in keys if self.pieces.get(k) == label]) for label in labels]

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
    links = read_table(os.path.join(directory, "links.csv"), LINKS_COLUMNS, required=False,
                       optional=(("previous_piece", int), ("current_piece", int)))
    pieces = split_pieces(read_table(os.path.join(directory, "pieces.csv"), PIECES_COLUMNS, required=False), odometry)
    if pieces:  # each piece of a split folder is its own odometry frame (it starts at the origin)
        odometry = Estimate("odometry", odometry.poses, {k: pieces.get(k, str(k[0])) for k in odometry.poses})
    return Run(odometry, slam, None if loops is None else loop_pairs(loops), timing, loop_poses, inputs, links,
               pieces)


def split_pieces(rows, odometry):
    """key -> "S.P" for the keyframes of the folders pieces.csv splits into several pieces (a
    tracking loss); empty without pieces.csv or when no folder was split."""
    by_session = {}
    for row in rows or []:
        by_session.setdefault(row["session"], []).append(row)
    out = {}
    for session, pieces in by_session.items():
        if len(pieces) < 2:
            continue
        for key in odometry.keys(lambda k: k[0] == session):
            for row in pieces:
                if row["first_index"] <= key[1] <= row["last_index"]:
                    out[key] = "%d.%d" % (session, row["piece"])
    return out


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


def is_bag_input(source):
    """Whether inputs.csv's `folder` is what offline_slam --bag read: a bag, or one dive's bags named together
    (a,b). A dataset folder is a directory; a bag is a file, or named *.bag when the run is scored elsewhere."""
    return all(os.path.isfile(part) or (part.endswith(".bag") and not os.path.isdir(part))
               for part in source.split(","))


def match_bags_to_folders(run, gt):
    """Renumbers the frames of the run's sessions read from bags by their folders' indexes, after checking that
    each bag is its folder's recording; returns notes for the report. A bag numbers its images by position
    (0, 1, ... in time order) and stamps them with their header stamps, which sit a constant offset after the
    folder's stamp_s (folder_to_bag's --start-time, or the clock of the recording): image k of the bag is the
    folder's frame k in stamp order, when the bag has as many images as the folder has frames, over the same
    span of time (first to last stamp, within 1 ms), at the same mean altitude (0.1 mm) when every frame of the
    folder has one (a frame without gets the bag's altitudes interpolated at its stamp). Anything else is
    refused (EvalError): never a frame scored against another frame's ground truth."""
    notes, renumber = [], {}
    for row in run.inputs or []:
        n = row["session"]
        if not is_bag_input(row["folder"]):
            continue
        if n < 0 or n >= len(gt.sessions):
            raise EvalError("the run read bag %s as session %d (inputs.csv) but only %d ground-truth folder(s) were "
                            "given: give each bag's dataset folder, in the run's order" % (row["folder"], n,
                                                                                          len(gt.sessions)))
        truth = gt.sessions[n]
        frames, first, last, altitude = folder_summary(truth)
        span, folder_span = row["last_stamp_s"] - row["first_stamp_s"], last - first
        every_altitude = all(math.isfinite(a) for a in truth.altitude.values())
        made = (row["frames"], 0.0, span, row["altitude_mean_m"] if every_altitude else altitude)
        if not same_summary(made, (frames, 0.0, folder_span, altitude)):
            raise EvalError("session %d of the run was read from bag %s (%d images over %.3f s, mean altitude %.4f m) "
                            "but %s has %d frames over %.3f s, mean altitude %.4f m: not that bag's folder, its frames "
                            "cannot be matched (give each bag's own dataset folder, in the run's order)"
                            % (n, row["folder"], row["frames"], span, row["altitude_mean_m"], truth.directory, frames,
                               folder_span, altitude))
        by_stamp = [truth.indexes[i] for i in sorted(range(frames), key=lambda i: truth.stamps[i])]
        renumber.update({(n, k): (n, index) for k, index in enumerate(by_stamp)})
        notes.append("session %d: bag %s matched to %s by position, its stamps %.3f s after the folder's%s"
                     % (n, row["folder"], truth.directory, row["first_stamp_s"] - first,
                        "" if every_altitude else " (mean altitude not compared: frames without altitude)"))
    if renumber:
        renumber_keys(run, lambda key: renumber.get(key, key))
    return notes


def renumber_keys(run, new_key):
    """Every (session, index) key of the run through new_key, in place."""
    for estimate in run.estimates():
        estimate.poses = {new_key(k): v for k, v in estimate.poses.items()}
        estimate.frame = {new_key(k): v for k, v in estimate.frame.items()}
    if run.loops is not None:
        run.loops = sorted(unordered(new_key(a), new_key(b)) for a, b in run.loops)
    if run.loop_poses is not None:
        run.loop_poses = {(new_key(a), new_key(b)): v for (a, b), v in run.loop_poses.items()}
    if run.pieces:
        run.pieces = {new_key(k): v for k, v in run.pieces.items()}


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
        if is_bag_input(row["folder"]):
            continue  # matched by match_bags_to_folders
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


def align_sim2(est_xy, gt_xy):
    """Best 2-D similarity (scale, yaw, t) minimising sum |s R(yaw) est + t - gt|^2 (Umeyama 1991)."""
    est_xy, gt_xy = np.asarray(est_xy, float), np.asarray(gt_xy, float)
    ce, cg = est_xy.mean(axis=0), gt_xy.mean(axis=0)
    e, g = est_xy - ce, gt_xy - cg
    cross = np.sum(e[:, 0] * g[:, 1] - e[:, 1] * g[:, 0])
    dot = np.sum(e[:, 0] * g[:, 0] + e[:, 1] * g[:, 1])
    var = float(np.sum(e * e))
    scale = math.hypot(cross, dot) / var if var > 0 else 1.0
    yaw = math.atan2(cross, dot)
    return scale, yaw, cg - scale * rotate(ce, yaw)


def ate_sim_rmse(est_xy, gt_xy):
    """(ATE RMSE after the best similarity alignment of the estimate onto the gt, its scale)."""
    scale, yaw, t = align_sim2(est_xy, gt_xy)
    aligned = scale * rotate_rows(np.asarray(est_xy, float), yaw) + t
    return ate_rmse(aligned, gt_xy), scale


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


STEP_NAMES = ("max_step_m", "max_step_gt_m", "max_step_excess_m", "max_step_err_m", "max_step_err_index",
              "max_turn_deg", "max_turn_gt_deg", "max_turn_err_deg")


def step_metrics(estimate, gt, keys):
    """Kinks: the largest step between consecutive keyframes (in `keys` order, same frame) against
    the ground truth's over the same pairs, and the largest error of one step (see the docstring)."""
    pairs = [(a, b) for a, b in zip(keys, keys[1:]) if estimate.same_frame(a, b)]
    rows = []
    for a, b in pairs:
        truth = gt.relative(a, b)
        if truth is None:
            continue
        est = estimate.relative(a, b)
        rows.append((a, b, float(np.hypot(est[0], est[1])), float(np.hypot(truth[0], truth[1])),
                     float(np.hypot(*(truth[:2] - est[:2]))), abs(wrap_angle(est[2])), abs(wrap_angle(truth[2])),
                     abs(wrap_angle(est[2] - truth[2]))))
    if not rows:
        return dict.fromkeys(STEP_NAMES, NA)
    worst = max(rows, key=lambda r: r[4])
    step, step_gt = max(r[2] for r in rows), max(r[3] for r in rows)
    return {"max_step_m": step, "max_step_gt_m": step_gt, "max_step_excess_m": step - step_gt,
            "max_step_err_m": worst[4], "max_step_err_index": worst[1][1],
            "max_turn_deg": math.degrees(max(r[5] for r in rows)),
            "max_turn_gt_deg": math.degrees(max(r[6] for r in rows)),
            "max_turn_err_deg": math.degrees(max(r[7] for r in rows))}


def e_k(estimate, gt, pairs):
    """The paper's e_k (35) over the pairs usable in the estimate: (mean error, pairs used)."""
    usable = [p for p in pairs if estimate.same_frame(*p)]
    trans, _ = relative_errors(estimate, gt, usable)
    return (float(np.mean(trans)) if len(trans) else NA), len(trans)


def absolute_metrics(estimate, gt_poses, keys, with_drift=True):
    """ATE, aligned ATE (rigid and similarity) and (optionally) path length and end drift over `keys`."""
    names = ["ate_rmse_m", "ate_aligned_rmse_m", "ate_sim_rmse_m", "sim_scale"] + (
        ["path_length_m", "end_drift_pct"] if with_drift else [])
    if not keys or any(k not in gt_poses for k in keys):
        return dict.fromkeys(names, NA)
    est_xy = np.array([estimate.poses[k][:2] for k in keys])
    gt_xy = np.array([gt_poses[k][:2] for k in keys])
    sim, scale = ate_sim_rmse(est_xy, gt_xy)
    out = {"ate_rmse_m": ate_rmse(est_xy, gt_xy), "ate_aligned_rmse_m": ate_aligned_rmse(est_xy, gt_xy),
           "ate_sim_rmse_m": sim, "sim_scale": scale}
    if with_drift:
        out.update(path_length_m=path_length(gt_xy), end_drift_pct=end_drift_pct(est_xy, gt_xy))
    return out


def ek_metrics(estimate, gt, pairs, kind):
    value, used = e_k(estimate, gt, pairs)
    return {"ek_%s_m" % kind: value, "ek_%s_pairs" % kind: used}


def session_metrics(estimate, gt, gt_poses, session, unit_keys=None):
    """Metrics of a session, or of the keys `unit_keys` of one of its pieces."""
    keys = estimate.keys(lambda k: k[0] == session and (unit_keys is None or k in unit_keys))
    out = {"n_keyframes": len(keys)}
    out.update(absolute_metrics(estimate, gt_poses, keys))
    out.update(rpe(estimate, gt, keys))
    out.update(step_metrics(estimate, gt, keys))
    gt_pairs = gt.loops or []
    inside = set(keys)
    out.update(ek_metrics(estimate, gt, [p for p in gt_pairs if p[0][0] == p[1][0] == session and (
        unit_keys is None or (p[0] in inside and p[1] in inside))], "intra"))
    if estimate.name == "slam":
        inter = [p for p in gt_pairs if p[0][0] != p[1][0] and session in (p[0][0], p[1][0])]
        out.update(ek_metrics(estimate, gt, inter, "inter"))
    return out


def map_metrics(estimate, gt, gt_poses, map_id, pieces=None):
    """Metrics of a map; n_sessions counts the pieces of split folders (`pieces`: key -> "S.P") apart."""
    keys = estimate.keys(lambda k: estimate.frame[k] == map_id)
    out = {"n_sessions": len({(pieces or {}).get(k, k[0]) for k in keys}), "n_keyframes": len(keys)}
    out.update(absolute_metrics(estimate, gt_poses, keys, with_drift=False))
    inside = [p for p in (gt.loops or []) if estimate.frame.get(p[0]) == map_id]
    out.update(ek_metrics(estimate, gt, [p for p in inside if p[0][0] == p[1][0]], "intra"))
    out.update(ek_metrics(estimate, gt, [p for p in inside if p[0][0] != p[1][0]], "inter"))
    return out


# ---------------------------------------------------------------------------------------------
# Mosaic consistency.

MOSAIC_GRID = (24, 18)  # sample pixels per image (columns, rows)
MOSAIC_MIN_SHARED = 0.25  # a pair overlaps when this fraction of the first's grid falls in the second


def normalised_gray(path):
    """The image as z-scored grey levels (PIL; Debian python3-pil, a matplotlib dependency)."""
    from PIL import Image
    try:
        with Image.open(path) as im:
            g = np.asarray(im.convert("L"), float)
    except OSError as e:
        raise EvalError("%s: cannot read the image (%s)" % (path, e)) from None
    return (g - g.mean()) / (g.std() or 1.0)


def rotate_rows(xy, yaw):
    """rotate() for each row of an N x 2 array."""
    c, s = math.cos(yaw), math.sin(yaw)
    return xy @ np.array([[c, s], [-s, c]])


def seabed_points(pose, pixels, camera, altitude):
    """Pixels (N x 2) of a nadir camera at `pose` and `altitude` -> seabed points (N x 2)."""
    ab = np.stack([(pixels[:, 0] - camera["cx"]) * altitude / camera["fx"],
                   (pixels[:, 1] - camera["cy"]) * altitude / camera["fy"]], axis=1)
    return np.asarray(pose[:2], float) + rotate_rows(ab, pose[2])


def image_pixels(pose, points, camera, altitude):
    """Seabed points (N x 2) -> pixels (N x 2) of the camera at `pose` (inverse of seabed_points)."""
    ab = rotate_rows(points - np.asarray(pose[:2], float), -pose[2])
    return np.stack([camera["cx"] + ab[:, 0] * camera["fx"] / altitude,
                     camera["cy"] + ab[:, 1] * camera["fy"] / altitude], axis=1)


def mosaic_consistency(keys, pose_sets, gt):
    """{set name: disagreement} over the pairs of `keys` overlapping under pose_sets["gt"], and the
    number of pairs (see the docstring's "Mosaic consistency")."""
    cams = {k: gt.sessions[k[0]].camera for k in keys}
    alt = {k: gt.sessions[k[0]].altitude[k[1]] for k in keys}
    grid = {}
    for k in keys:
        c = cams[k]
        u = np.linspace(0.05, 0.95, MOSAIC_GRID[0]) * (c["image_width"] - 1)
        v = np.linspace(0.05, 0.95, MOSAIC_GRID[1]) * (c["image_height"] - 1)
        grid[k] = np.stack(np.meshgrid(u, v), axis=-1).reshape(-1, 2)

    def inside(px, c):
        return (px[:, 0] >= 0) & (px[:, 1] >= 0) & (px[:, 0] <= c["image_width"] - 1) & \
            (px[:, 1] <= c["image_height"] - 1)

    truth = pose_sets["gt"]
    pairs = []
    for i, a in enumerate(keys):
        for b in keys[i + 1:]:
            reach = max(cams[a]["image_width"], cams[a]["image_height"]) * alt[a] / cams[a]["fx"] + \
                max(cams[b]["image_width"], cams[b]["image_height"]) * alt[b] / cams[b]["fx"]
            if np.hypot(truth[a][0] - truth[b][0], truth[a][1] - truth[b][1]) > reach:
                continue
            px = image_pixels(truth[b], seabed_points(truth[a], grid[a], cams[a], alt[a]), cams[b], alt[b])
            if inside(px, cams[b]).mean() >= MOSAIC_MIN_SHARED:
                pairs.append((a, b))
    images = {}

    def image(k):
        if k not in images:
            truth_k = gt.sessions[k[0]]
            images[k] = normalised_gray(os.path.join(truth_k.directory, truth_k.images[k[1]]))
        return images[k]

    out = {}
    for name, poses in pose_sets.items():
        total, count = 0.0, 0
        for a, b in pairs:
            px = image_pixels(poses[b], seabed_points(poses[a], grid[a], cams[a], alt[a]), cams[b], alt[b])
            ok = inside(px, cams[b])
            if not ok.any():
                continue
            ia, ib = image(a), image(b)
            pa = np.rint(grid[a][ok]).astype(int)
            pb = np.rint(px[ok]).astype(int)
            total += float(np.abs(ia[pa[:, 1], pa[:, 0]] - ib[pb[:, 1], pb[:, 0]]).sum())
            count += int(ok.sum())
        out[name] = total / count if count else NA
    return out, len(pairs)


def mosaic_metrics(estimate, gt_poses, gt, map_id):
    keys = estimate.keys(lambda k: estimate.frame[k] == map_id)
    if any(k not in gt_poses for k in keys):
        return dict.fromkeys(("mosaic_disagreement", "mosaic_disagreement_gt", "mosaic_ratio", "mosaic_pairs"), NA)
    scores, pairs = mosaic_consistency(keys, {"slam": {k: estimate.poses[k] for k in keys},
                                              "gt": {k: gt_poses[k] for k in keys}}, gt)
    est, best = scores["slam"], scores["gt"]
    return {"mosaic_disagreement": est, "mosaic_disagreement_gt": best,
            "mosaic_ratio": est / best if est is not NA and best else NA, "mosaic_pairs": pairs}


MOSAIC_PNG_MAX_SIDE = 600  # --mosaic-png: the coarsest raster keeps the ground truth's extent within this


def mosaic_footprint(pose, camera, altitude):
    """Seabed corners (4 x 2) of a keyframe's image: the pixel edges put down by seabed_points."""
    w, h = camera["image_width"], camera["image_height"]
    return seabed_points(pose, np.array([[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5]]),
                         camera, altitude)


def mosaic_raster(keys, pose_sets, gt):
    """(x0, y0, res, width, height) of one raster for every pose set: image axes (x right, y down),
    x0 / y0 the left / top edge. The resolution comes from the ground truth alone (the median
    keyframe's ground pixel, coarser when its extent would exceed MOSAIC_PNG_MAX_SIDE) and the
    edges are multiples of it, so a pixel of the ground truth's mosaic stays the same pixel, at the
    same place, whatever the estimate; the extent covers every pose set's footprints."""
    corners = {name: np.concatenate([mosaic_footprint(poses[k], gt.sessions[k[0]].camera,
                                                      gt.sessions[k[0]].altitude[k[1]]) for k in keys])
               for name, poses in pose_sets.items()}
    truth = corners["gt"]
    side = float(np.max(truth.max(axis=0) - truth.min(axis=0)))
    ground_px = float(np.median([gt.sessions[k[0]].altitude[k[1]] / gt.sessions[k[0]].camera["fx"] for k in keys]))
    res = max(ground_px, side / MOSAIC_PNG_MAX_SIDE)
    everything = np.concatenate(list(corners.values()))
    lo = np.floor(everything.min(axis=0) / res) * res
    hi = np.ceil(everything.max(axis=0) / res) * res
    width, height = (int(round(v)) for v in (hi - lo) / res)
    return float(lo[0]), float(lo[1]), res, max(width, 1), max(height, 1)


def mosaic_colour(path, gains, factor):
    """The image as float RGB, multiplied by its per-channel gains, shrunk by `factor` (<= 1; PIL's
    box filter, so a coarse mosaic is not aliased) -> (image, x scale, y scale)."""
    from PIL import Image
    try:
        with Image.open(path) as im:
            rgb = im.convert("RGB")
            if factor < 1.0:
                size = (max(1, int(round(rgb.width * factor))), max(1, int(round(rgb.height * factor))))
                scale = (size[0] / rgb.width, size[1] / rgb.height)
                rgb = rgb.resize(size, Image.BOX)
            else:
                scale = (1.0, 1.0)
            return np.asarray(rgb, float) * gains, scale
    except OSError as e:
        raise EvalError("%s: cannot read the image (%s)" % (path, e)) from None


def render_mosaics(keys, pose_sets, gt):
    """{set name: H x W x 4 uint8 RGBA} of the keyframes `keys` drawn by each pose set on the same
    raster (mosaic_raster), and the raster. Each raster pixel is put on the seabed and looked up in
    every keyframe that sees it by image_pixels (the projection of the mosaic score), nearest pixel;
    the keyframes seeing a pixel are averaged, so a misplaced keyframe shows as a ghost. Each image
    is scaled per colour channel to the map's mean colour (the missions' light and water differ);
    alpha 0 where no keyframe is drawn."""
    x0, y0, res, width, height = raster = mosaic_raster(keys, pose_sets, gt)
    paths = {k: os.path.join(gt.sessions[k[0]].directory, gt.sessions[k[0]].images[k[1]]) for k in keys}
    means = {}
    for k in keys:
        image, _ = mosaic_colour(paths[k], 1.0, 0.25)
        means[k] = image.reshape(-1, 3).mean(axis=0)
    target = np.mean(list(means.values()), axis=0)
    out = {}
    for name, poses in pose_sets.items():
        total = np.zeros((height, width, 3))
        count = np.zeros((height, width))
        for k in keys:
            cam, alt = gt.sessions[k[0]].camera, gt.sessions[k[0]].altitude[k[1]]
            corners = (mosaic_footprint(poses[k], cam, alt) - (x0, y0)) / res
            c0, r0 = np.maximum(np.floor(corners.min(axis=0)).astype(int), 0)
            c1, r1 = np.minimum(np.ceil(corners.max(axis=0)).astype(int), (width, height))
            if c0 >= c1 or r0 >= r1:
                continue
            cc, rr = np.meshgrid(np.arange(c0, c1), np.arange(r0, r1))
            ground = np.stack([x0 + (cc.ravel() + 0.5) * res, y0 + (rr.ravel() + 0.5) * res], axis=1)
            image, (sx, sy) = mosaic_colour(paths[k], target / np.maximum(means[k], 1e-6),
                                            min(1.0, alt / cam["fx"] / res))
            px = image_pixels(poses[k], ground, cam, alt)
            u = np.rint((px[:, 0] + 0.5) * sx - 0.5).astype(int)  # pixel centres: the shrink maps edge to edge
            v = np.rint((px[:, 1] + 0.5) * sy - 0.5).astype(int)
            ok = (u >= 0) & (v >= 0) & (u < image.shape[1]) & (v < image.shape[0])
            r, c = rr.ravel()[ok], cc.ravel()[ok]
            total[r, c] += image[v[ok], u[ok]]
            count[r, c] += 1
        rgba = np.zeros((height, width, 4), np.uint8)
        seen = count > 0
        rgba[seen, :3] = np.clip(np.rint(total[seen] / count[seen][:, None]), 0, 255).astype(np.uint8)
        rgba[seen, 3] = 255
        out[name] = rgba
    return out, raster


def write_mosaic_pngs(ev, run, gt, directory):
    """--mosaic-png: per map whose ground truth is known, map_<m>_slam.png (the estimated poses) and
    map_<m>_gt.png (the ground truth's), each with a world file (.pgw, z-up map frame as
    export_survey writes it). Returns the lines printed."""
    from PIL import Image
    os.makedirs(directory, exist_ok=True)
    lines = []
    gt_poses = ev.gt_poses.get("slam", {})
    scores = ev.nested().get("map", {})
    for map_id in sorted(set(run.slam.frame.values())):
        keys = run.slam.keys(lambda k: run.slam.frame[k] == map_id)
        if any(k not in gt_poses for k in keys):
            lines.append("map %d: no mosaic PNGs (its ground truth needs world_gt.csv)" % map_id)
            continue
        images, (x0, y0, res, width, height) = render_mosaics(
            keys, {"slam": {k: run.slam.poses[k] for k in keys}, "gt": {k: gt_poses[k] for k in keys}}, gt)
        written = []
        for name in ("slam", "gt"):
            path = os.path.join(directory, "map_%d_%s.png" % (map_id, name))
            with AtomicFile(path, "wb") as f:
                Image.fromarray(images[name], "RGBA").save(f, format="PNG", optimize=True)
            # image-axes y down = z-up y up: -y
            write_atomically(path[:-4] + ".pgw", "%.12g\n0\n0\n%.12g\n%.12g\n%.12g\n" % (
                res, -res, x0 + res / 2, -(y0 + res / 2)))
            written.append(path)
        m = scores.get(str(map_id), {}).get("slam", {})
        score = ""
        if m.get("mosaic_disagreement") is not None:
            score = "; disagreement %s, ground truth's %s, ratio %s" % tuple(
                md_value(m[n]) for n in ("mosaic_disagreement", "mosaic_disagreement_gt", "mosaic_ratio"))
        lines.append("map %d: %s and %s, %d x %d px at %.4f m/px, %d keyframes%s" % (
            map_id, written[0], written[1], width, height, res, len(keys), score))
    return lines


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


NEAR_FRAMES = 1  # recall_all: an accepted loop within this many frame indexes of each frame of a gt pair


def near(key, other):
    return key[0] == other[0] and abs(key[1] - other[1]) <= NEAR_FRAMES


def found_near(gt_pairs, accepted, verdict):
    """The gt pairs found by an accepted loop, not judged wrong, that joins keyframes within
    NEAR_FRAMES of each of the pair's frames (either order)."""
    good = [p for p in accepted if verdict.get(p) is not False]
    return [p for p in gt_pairs if any((near(p[0], a) and near(p[1], b)) or (near(p[0], b) and near(p[1], a))
                                       for a, b in good)]


def loop_metrics(run, gt, verdict):
    """Precision and recall per kind (intra, inter, all)."""
    keyframes = run.keyframes()
    out = {}
    for kind in LOOP_KINDS:
        m = dict.fromkeys(("accepted", "correct", "precision", "gt_pairs", "gt_pairs_keyframes", "found",
                           "recall", "found_near", "recall_all"), NA)
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
                m["found_near"] = len(found_near(gt_pairs, of_kind(run.loops, kind), verdict))
                m["recall_all"] = m["found_near"] / len(gt_pairs) if gt_pairs else NA
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


def evaluate(run, gt, loop_true_dist=None, mosaic_score=False):
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
        units = run.units(session)
        if len(units) > 1:
            ev.notes.append("session %d was split by tracking loss into %d pieces (pieces.csv): scored per piece, "
                            "%s" % (session, len(units), ", ".join(str(u) for u, _ in units)))
        for unit, keys in units:
            for estimate in run.estimates():
                if session in estimate.sessions():
                    ev.add("session", unit, estimate.name, session_metrics(
                        estimate, gt, ev.gt_poses[estimate.name], session, None if len(units) == 1 else set(keys)))
    if run.slam is not None:
        for map_id in sorted(set(run.slam.frame.values())):
            metrics = map_metrics(run.slam, gt, ev.gt_poses["slam"], map_id, run.pieces)
            if mosaic_score:
                metrics.update(mosaic_metrics(run.slam, ev.gt_poses["slam"], gt, map_id))
            ev.add("map", map_id, "slam", metrics)
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
               ("aligned ATE (m)", "ate_aligned_rmse_m"), ("similarity ATE (m)", "ate_sim_rmse_m"))
MOSAIC_COLUMNS = (("disagreement", "mosaic_disagreement"), ("ground truth's", "mosaic_disagreement_gt"),
                  ("ratio", "mosaic_ratio"), ("pairs", "mosaic_pairs"))
LOOP_COLUMNS = ("accepted", "correct", "precision", "gt_pairs", "gt_pairs_keyframes", "found", "recall",
                "found_near", "recall_all")
STEP_COLUMNS = (("largest step (m)", "max_step_m"), ("ground truth's (m)", "max_step_gt_m"),
                ("excess (m)", "max_step_excess_m"), ("worst step error (m)", "max_step_err_m"),
                ("at keyframe", "max_step_err_index"), ("largest turn (deg)", "max_turn_deg"),
                ("ground truth's (deg)", "max_turn_gt_deg"), ("worst turn error (deg)", "max_turn_err_deg"))
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
    rows = [[sid, est] + metric_cells(m, STEP_COLUMNS) for sid, by_est in data.get("session", {}).items()
            for est, m in by_est.items() if "max_step_m" in m]
    parts += ["## Steps between consecutive keyframes (kinks)",
              md_table(["session", "estimate"] + [h for h, _ in STEP_COLUMNS], rows)]
    rows = [[mid] + metric_cells(m["slam"], MAP_COLUMNS) + [with_pairs(m["slam"], "intra"),
                                                            with_pairs(m["slam"], "inter")]
            for mid, m in data.get("map", {}).items()]
    if rows:
        parts += ["## Maps (slam)", md_table(["map"] + [h for h, _ in MAP_COLUMNS] + list(EK_HEADERS), rows)]
    rows = [[mid] + metric_cells(m["slam"], MOSAIC_COLUMNS) for mid, m in data.get("map", {}).items()
            if "mosaic_ratio" in m["slam"]]
    if rows:
        parts += ["## Mosaic consistency (slam)", md_table(["map"] + [h for h, _ in MOSAIC_COLUMNS], rows)]
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
    with AtomicFile(os.path.join(report_dir, "metrics.csv"), "w", newline="") as f:
        out = csv.writer(f, lineterminator="\n")
        out.writerow(("scope", "id", "estimate", "metric", "value"))
        out.writerows(row[:4] + (csv_value(row[4]),) for row in ev.rows)
    write_atomically(os.path.join(report_dir, "metrics.json"), json.dumps(ev.nested(), indent=2) + "\n")
    text = markdown(ev)
    write_atomically(os.path.join(report_dir, "metrics.md"), text)
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


@dataclass
class Layer:
    """One thing drawn in a figure: a polyline (or separate segments) in one style."""
    kind: str      # ground_truth, odometry, slam, loop_correct, loop_wrong, loop_unjudged, join_link
    label: str     # legend entry ("" for none)
    segments: list  # arrays of (x, y) rows: one polyline each
    colour: str
    style: str     # matplotlib line style: "-", "--", ":"
    width: float
    zorder: float
    start_marker: bool = False


# Sessions in their own colours (matplotlib's tab10, cycled); loops and links in colours of their own.
SESSION_COLOURS = ("tab:blue", "tab:orange", "tab:purple", "tab:brown", "tab:pink", "tab:olive", "tab:cyan",
                   "tab:gray")
LOOP_STYLE = {True: ("loop_correct", "correct loop", "tab:green"), False: ("loop_wrong", "wrong loop", "tab:red"),
              None: ("loop_unjudged", "loop (not judged)", "darkgray")}
# A map whose extent is this many times longer than wide gets a second, stretched view.
THIN_MAP_RATIO = 5.0


def session_colour(session):
    return SESSION_COLOURS[session % len(SESSION_COLOURS)]


def anchored(poses, keys, anchor_key, anchor_pose):
    """Poses of `keys` moved rigidly so that anchor_key lands on anchor_pose (odometry drawn from
    where the SLAM puts the session's first keyframe, so the two can be compared by eye)."""
    if anchor_key not in poses:
        return {}
    to_anchor = compose(anchor_pose, invert(poses[anchor_key]))
    return {k: compose(to_anchor, poses[k]) for k in keys if k in poses}


def polyline(poses, keys):
    xy = [poses[k][:2] for k in keys if k in poses]
    return [np.array(xy)] if xy else []


def trajectory_layers(session, keys, gt, odometry, slam, with_label, pieces=None):
    """Ground truth (black, dotted), odometry (dashed, under) and SLAM (solid, over) of one session.
    The odometry of each piece (`pieces`: key lists; a tracking loss restarts the odometry at the
    origin) starts where the SLAM, or without it the ground truth, puts the piece's first keyframe."""
    colour = session_colour(session)
    layers = [Layer("ground_truth", "ground truth" if with_label else "", polyline(gt, keys), "black", ":", 1.0, 2)]
    segments = []
    for piece in pieces or [keys]:
        first = next((k for k in piece if k in odometry), None)
        anchor = (slam or gt).get(first) if first is not None else None
        segments += polyline(anchored(odometry, piece, first, anchor) if anchor is not None else odometry, piece)
    layers.append(Layer("odometry", "odometry s%d" % session, segments, colour, "--", 1.0, 1))
    if slam:
        segments = [seg for piece in pieces or [keys] for seg in polyline(slam, piece)]  # broken between pieces
        layers.append(Layer("slam", "SLAM s%d" % session, segments, colour, "-", 1.6, 3, True))
    return [layer for layer in layers if layer.segments]


def loop_layers(verdict, positions, inside):
    """Accepted loops between keyframes that `inside` accepts, drawn between `positions`, one layer per verdict."""
    by_verdict = {}
    for pair, ok in sorted(verdict.items(), key=lambda item: item[0]):
        if all(inside(k) and k in positions for k in pair):
            by_verdict.setdefault(ok, []).append(np.array([positions[k][:2] for k in pair]))
    return [Layer(LOOP_STYLE[ok][0], LOOP_STYLE[ok][1], segs, LOOP_STYLE[ok][2], "-", 0.7, 2.5)
            for ok, segs in sorted(by_verdict.items(), key=lambda item: str(item[0]))]


def join_link_layers(links, slam, map_id, pieces=None):
    """The join links of a map (links.csv): from the last keyframe of the earlier session to the
    first of the later one, as the SLAM places them."""
    segs = []
    for link in links or []:
        a, b = link["previous_session"], link["current_session"]
        if link["map"] != map_id:
            continue
        ka = [k for k in slam.keys(lambda k: k[0] == a) if slam.frame[k] == map_id]
        kb = [k for k in slam.keys(lambda k: k[0] == b) if slam.frame[k] == map_id]
        if a == b:  # pieces of one folder (a tracking loss): located by pieces.csv
            if pieces is None or link.get("previous_piece") is None:
                continue
            ka = [k for k in ka if pieces.get(k) == "%d.%d" % (a, link["previous_piece"])]
            kb = [k for k in kb if pieces.get(k) == "%d.%d" % (b, link["current_piece"])]
        if ka and kb:
            segs.append(np.array([slam.poses[ka[-1]][:2], slam.poses[kb[0]][:2]]))
    return [Layer("join_link", "join link", segs, "black", "-", 2.4, 4)] if segs else []


def map_layers(ev, run, map_id):
    slam = run.slam
    keys = slam.keys(lambda k: slam.frame[k] == map_id)
    layers = []
    for n, session in enumerate(sorted({k[0] for k in keys})):
        skeys = [k for k in keys if k[0] == session]
        pieces = [[k for k in unit if k in skeys] for _, unit in run.units(session)]
        layers += trajectory_layers(session, skeys, ev.gt_poses["slam"], run.odometry.poses, slam.poses, n == 0,
                                    [p for p in pieces if p])
    layers += loop_layers(ev.verdict, slam.poses, lambda k: slam.frame.get(k) == map_id)
    layers += join_link_layers(run.links, slam, map_id, run.pieces)
    return layers


def session_layers(ev, run, gt, session):
    keys = sorted(k for k in run.keyframes() if k[0] == session)
    truth = session_frame_truth(gt, keys)
    slam = {}
    if run.slam is not None:
        slam = slam_in_session_frame(ev, run.slam, truth, run.slam.keys(lambda k: k[0] == session))
    layers = trajectory_layers(session, keys, truth, run.odometry.poses, slam, True,
                               [unit for _, unit in run.units(session)])
    # Loops inside the session, between the SLAM positions (the odometry's without SLAM).
    positions = slam or anchored(run.odometry.poses, keys, keys[0], truth[keys[0]])
    return layers + loop_layers(ev.verdict, positions, lambda k: k[0] == session)


def extent(layers):
    xy = np.vstack([seg for layer in layers for seg in layer.segments])
    return xy.min(axis=0), xy.max(axis=0)


def is_thin(layers):
    lo, hi = extent(layers)
    size = np.maximum(hi - lo, 1e-9)
    return size.max() / size.min() > THIN_MAP_RATIO


def draw_layers(ax, layers):
    for layer in layers:
        for n, seg in enumerate(layer.segments):
            ax.plot(seg[:, 0], seg[:, 1], layer.style, color=layer.colour, linewidth=layer.width, zorder=layer.zorder,
                    label=layer.label if n == 0 and layer.label else None, marker="." if layer.kind == "slam" else None,
                    markersize=2.5)
        if layer.start_marker and layer.segments:
            x, y = layer.segments[0][0]
            ax.plot(x, y, "o", color=layer.colour, markersize=7, markerfacecolor="none", zorder=layer.zorder)


def style_axes(ax, title, equal=True):
    ax.set_title(title, fontsize=10)
    ax.set_xlabel("x (m, image u axis)")
    ax.set_ylabel("y (m, image v axis)")
    if equal:
        ax.set_aspect("equal", adjustable="datalim")
    ax.invert_yaxis()
    ax.grid(True, linewidth=0.3)


def render(plt, layers, title, path):
    """One figure: equal axes; a long thin one (is_thin) gets a second, stretched view below, so
    its detail stays legible. Returns the number of views drawn."""
    thin = is_thin(layers)
    if thin:
        fig, (ax, stretched) = plt.subplots(2, 1, figsize=(8, 8), gridspec_kw={"height_ratios": [1, 2]})
    else:
        fig, ax = plt.subplots(figsize=(7, 6))
    draw_layers(ax, layers)
    style_axes(ax, title + " (equal axes; o = start)")
    if thin:
        draw_layers(stretched, layers)
        style_axes(stretched, "the same, stretched across (not to scale)", equal=False)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    with AtomicFile(path, "wb") as f:
        fig.savefig(f, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return 2 if thin else 1


def write_plots(ev, run, gt, report_dir):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    written = []
    for session in sorted({k[0] for k in run.keyframes()}):
        written.append(os.path.join(report_dir, "session_%d.png" % session))
        render(plt, session_layers(ev, run, gt, session), "session %d (session frame)" % session, written[-1])
    if run.slam is not None:
        for map_id in sorted(set(run.slam.frame.values())):
            written.append(os.path.join(report_dir, "map_%d.png" % map_id))
            render(plt, map_layers(ev, run, map_id), "map %d (map frame)" % map_id, written[-1])
    return written


# ---------------------------------------------------------------------------------------------
# HTML report: one self-contained file (inline style, figures as data: URIs, no external link).

HTML_STYLE = """body{font-family:sans-serif;margin:2em auto;max-width:1100px;color:#222}
table{border-collapse:collapse;margin:0.5em 0 1.5em}th,td{border:1px solid #bbb;padding:3px 8px;text-align:right}
th{background:#eef}td:first-child,th:first-child{text-align:left}figure{display:inline-block;vertical-align:top;width:48%;margin:0 1% 1em 0}
figcaption{font-size:90%;color:#555}pre{background:#f6f6f6;padding:0.8em;overflow-x:auto;font-size:85%}"""


def markdown_to_html(text):
    """The subset of markdown that markdown() writes: # headings, | tables |, - lists."""
    import html
    out, table, items = [], [], []

    def flush():
        if table:
            head, body = table[0], table[2:]  # table[1] is the |---| rule
            out.append("<table><tr>%s</tr>%s</table>" % ("".join("<th>%s</th>" % html.escape(c) for c in head), "".join(
                "<tr>%s</tr>" % "".join("<td>%s</td>" % html.escape(c) for c in row) for row in body)))
            table.clear()
        if items:
            out.append("<ul>%s</ul>" % "".join("<li>%s</li>" % html.escape(i) for i in items))
            items.clear()

    for line in text.splitlines():
        if line.startswith("|"):
            table.append([c.strip() for c in line.strip().strip("|").split("|")])
            continue
        if line.startswith("- "):
            items.append(line[2:])
            continue
        flush()
        level = len(line) - len(line.lstrip("#"))
        if 0 < level <= 3 and line[level:level + 1] == " ":
            out.append("<h%d>%s</h%d>" % (level + 1, html.escape(line[level + 1:]), level + 1))
    flush()
    return "\n".join(out)


def write_html(ev, run_dir, report_dir, figures, command):
    """report.html: the metrics tables, the figures, the run's inputs and configuration, the command."""
    import base64
    import html
    parts = ["<!DOCTYPE html>", "<html><head><meta charset=\"utf-8\"><title>uw_multislam report: %s</title>"
             % html.escape(os.path.basename(os.path.normpath(run_dir))), "<style>%s</style></head><body>" % HTML_STYLE,
             "<h1>uw_multislam report</h1>",
             "<p>Run <code>%s</code>, scored by <code>%s</code>.</p>" % (html.escape(run_dir), html.escape(command))]
    parts.append(markdown_to_html(markdown(ev).replace("# SLAM evaluation", "## Metrics", 1)))
    parts.append("<h2>Figures</h2>")
    for path in figures:
        with open(path, "rb") as f:
            data = base64.b64encode(f.read()).decode("ascii")
        name = os.path.splitext(os.path.basename(path))[0].replace("_", " ")
        parts.append("<figure><img alt=\"%s\" src=\"data:image/png;base64,%s\" style=\"width:100%%\">"
                     "<figcaption>%s</figcaption></figure>" % (name, data, name))
    inputs = os.path.join(run_dir, "inputs.csv")
    if os.path.isfile(inputs):
        with open(inputs) as f:
            rows = list(csv.reader(f))
        parts.append("<h2>Inputs</h2>" + markdown_to_html("\n".join(
            "| " + " | ".join(r) + " |" + ("\n|" + "---|" * len(r) if n == 0 else "") for n, r in enumerate(rows))))
    config = os.path.join(run_dir, "config.yaml")
    parts.append("<h2>Configuration</h2>")
    if os.path.isfile(config):
        with open(config) as f:
            parts.append("<pre>%s</pre>" % html.escape(f.read()))
    else:
        parts.append("<p>The run has no config.yaml (record_run.py does not write one; see the launch parameters).</p>")
    parts.append("</body></html>")
    path = os.path.join(report_dir, "report.html")
    write_atomically(path, "\n".join(parts) + "\n")
    return path


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
    parser.add_argument("--inputs", metavar="FILE",
                        help="an inputs.csv describing the run's sessions, in place of the run's own (which has no "
                             "row for the sessions a store held before the run; season.py writes one)")
    parser.add_argument("--loops-gt", metavar="FILE", help="loops_gt.csv: the revisits to find")
    parser.add_argument("--report", required=True, metavar="REPORT_DIR", help="where to write the report")
    parser.add_argument("--no-plots", action="store_true", help="do not write PNG plots")
    parser.add_argument("--html", action="store_true",
                        help="also write report.html: one self-contained file with the tables, the plots, the "
                             "run's inputs and configuration (without figures under --no-plots)")
    parser.add_argument("--mosaic-score", action="store_true",
                        help="per map, the mosaic consistency score (reads the keyframes' images)")
    parser.add_argument("--mosaic-png", metavar="DIR",
                        help="per map, its mosaic drawn from the estimated poses (map_<m>_slam.png) and from the "
                             "ground truth's (map_<m>_gt.png), same extent and resolution, with world files, into "
                             "DIR (implies --mosaic-score)")
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
        if args.inputs is not None:
            run.inputs = read_table(args.inputs, INPUTS_COLUMNS)
        notes = match_bags_to_folders(run, gt)
        notes += check_run_against_truth(run, gt)
        ev = evaluate(run, gt, args.loop_true_dist, args.mosaic_score or args.mosaic_png is not None)
        ev.notes += notes
        text = write_report(ev, args.report)
        figures = [] if args.no_plots else write_plots(ev, run, gt, args.report)
        if args.html:
            command = "evaluate.py " + " ".join(sys.argv[1:] if argv is None else [str(a) for a in argv])
            write_html(ev, args.run, args.report, sorted(figures, key=lambda p: "map" not in p), command)
        mosaic_lines = []
        if args.mosaic_png is not None:
            if run.slam is None:
                raise EvalError("%s: no trajectory.csv: --mosaic-png draws the slam estimate" % args.run)
            mosaic_lines = write_mosaic_pngs(ev, run, gt, args.mosaic_png)
    except (EvalError, OSError) as e:
        print("evaluate.py: error: %s" % e, file=sys.stderr)
        return 1
    print(text, end="")
    for line in mosaic_lines:
        print("mosaic PNGs of " + line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
