"""Tests of src/tools/evaluate.py. Every input is built in tmp_path; nothing reads ../shared."""
import csv
import importlib.util
import json
import math
import os
import subprocess

import numpy as np
import pytest

TOOL = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "src", "tools", "evaluate.py")
_spec = importlib.util.spec_from_file_location("evaluate", TOOL)
ev = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(ev)

ALTITUDE = 2.0  # with image_height 240 and fy 1000: footprint height 0.48 m


# ---------------------------------------------------------------------------------------------
# Builders.

def write_csv(path, header, rows):
    with open(path, "w", newline="") as f:
        out = csv.writer(f, lineterminator="\n")
        out.writerow(header.split(","))
        out.writerows(rows)


def write_session(directory, poses):
    """A dataset folder whose gt is `poses` (list of (x, y, yaw), frame i = index i)."""
    os.makedirs(directory, exist_ok=True)
    write_csv(os.path.join(directory, "gt.csv"), "index,image,x_m,y_m,yaw_rad",
              [(i, "%04d.png" % i) + tuple(p) for i, p in enumerate(poses)])
    write_csv(os.path.join(directory, "frames.csv"), "index,image,stamp_s,altitude_m",
              [(i, "%04d.png" % i, 0.5 * i, ALTITUDE) for i in range(len(poses))])
    with open(os.path.join(directory, "camera.yaml"), "w") as f:
        f.write("image_width: 320\nimage_height: 240\nfx: 1000.0\nfy: 1000.0\ncx: 160.0\ncy: 120.0\n")
    return str(directory)


def write_run(directory, odometry, trajectory=None, loops=None, timing=None):
    """odometry: {session: [(index, pose)]}; trajectory: {session: [(index, map, pose)]};
    loops: [((s, i), (s, i))]; timing: list of rows."""
    os.makedirs(directory, exist_ok=True)
    write_csv(os.path.join(directory, "odometry.csv"), "session,index,x_m,y_m,yaw_rad",
              [(s, i) + tuple(p) for s, rows in odometry.items() for i, p in rows])
    if trajectory is not None:
        write_csv(os.path.join(directory, "trajectory.csv"), "session,index,map,x_m,y_m,yaw_rad",
                  [(s, i, m) + tuple(p) for s, rows in trajectory.items() for i, m, p in rows])
    if loops is not None:
        write_csv(os.path.join(directory, "loops.csv"), "session_a,index_a,session_b,index_b,kind,inliers",
                  [(a[0], a[1], b[0], b[1], "local" if a[0] == b[0] else "global", 30) for a, b in loops])
    if timing is not None:
        write_csv(os.path.join(directory, "timing.csv"), "stage,calls,total_ms,mean_ms,max_ms", timing)
    return str(directory)


def write_loops_gt(path, pairs):
    write_csv(path, "session_a,index_a,session_b,index_b", [(a[0], a[1], b[0], b[1]) for a, b in pairs])
    return str(path)


def write_world_gt(path, sessions):
    write_csv(path, "session,index,x_m,y_m,yaw_rad",
              [(s, i) + tuple(p) for s, poses in enumerate(sessions) for i, p in enumerate(poses)])
    return str(path)


def lawnmower(n=12, step=0.2):
    """A path that turns: out along x, a corner, then down along y (x right, y down)."""
    poses = [(step * i, 0.0, 0.0) for i in range(n // 2)]
    corner = poses[-1][0]
    poses += [(corner, step * (i + 1), math.pi / 2) for i in range(n - len(poses))]
    return poses


def in_frame(origin, poses):
    """`poses` (given in a world frame) expressed in the frame of `origin`."""
    o = np.array(origin)
    return [tuple(ev.relative(o, np.array(p))) for p in poses]


def to_world(origin, poses):
    o = np.array(origin)
    return [tuple(ev.compose(o, np.array(p))) for p in poses]


def indexed(poses, keyframes=None):
    keyframes = range(len(poses)) if keyframes is None else keyframes
    return [(i, poses[i]) for i in keyframes]


def run_main(args):
    return ev.main([str(a) for a in args])


def evaluate_dirs(tmp_path, sessions, run, world=None, loops_gt=None, extra=()):
    args = ["--run", run, "--report", tmp_path / "report", "--no-plots"]
    for s in sessions:
        args += ["--session", s]
    if world:
        args += ["--world-gt", world]
    if loops_gt:
        args += ["--loops-gt", loops_gt]
    assert run_main(args + list(extra)) == 0
    with open(tmp_path / "report" / "metrics.json") as f:
        return json.load(f)


def metric(data, scope, ident, estimate, name):
    return data[scope][str(ident)][estimate][name]


# ---------------------------------------------------------------------------------------------
# Pose helpers.

def test_wrap_angle_is_half_open_at_minus_pi():
    assert ev.wrap_angle(math.pi) == pytest.approx(math.pi)
    assert ev.wrap_angle(-math.pi) == pytest.approx(math.pi)
    assert ev.wrap_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
    assert ev.wrap_angle(-0.25) == pytest.approx(-0.25)


def test_relative_position_is_rotated_by_minus_yaw_of_first_pose():
    a = np.array([1.0, 2.0, math.pi / 2])  # facing +y
    b = np.array([1.0, 3.0, math.pi])      # one metre further along a's x axis
    rel = ev.relative(a, b)
    assert rel == pytest.approx([1.0, 0.0, math.pi / 2])
    assert ev.compose(a, rel) == pytest.approx(b)


def test_se2_alignment_recovers_a_rigid_motion():
    gt_xy = np.array([p[:2] for p in lawnmower()])
    moved = [tuple(ev.compose(np.array([0.5, -0.3, 0.4]), np.array([x, y, 0.0]))[:2]) for x, y in gt_xy]
    assert ev.ate_rmse(moved, gt_xy) > 0.3
    assert ev.ate_aligned_rmse(moved, gt_xy) == pytest.approx(0.0, abs=1e-12)


# ---------------------------------------------------------------------------------------------
# Trajectory metrics.

def test_estimate_equal_to_ground_truth_scores_zero(tmp_path):
    gt = lawnmower()
    s0 = write_session(tmp_path / "s0", gt)
    pairs = [((0, 0), (0, 11)), ((0, 2), (0, 9))]
    loops_gt = write_loops_gt(tmp_path / "loops_gt.csv", pairs)
    run = write_run(tmp_path / "run", {0: indexed(gt)}, {0: [(i, 0, p) for i, p in indexed(gt)]})
    data = evaluate_dirs(tmp_path, [s0], run, loops_gt=loops_gt)
    for estimate in ("odometry", "slam"):
        m = data["session"]["0"][estimate]
        for name in ("ate_rmse_m", "ate_aligned_rmse_m", "end_drift_pct", "rpe_trans_rmse_m",
                     "rpe_rot_rmse_deg", "ek_intra_m"):
            assert m[name] == pytest.approx(0.0, abs=1e-9), (estimate, name)
        assert m["n_keyframes"] == 12
        assert m["ek_intra_pairs"] == 2
        assert m["path_length_m"] == pytest.approx(12 * 0.2 - 0.2)
    assert metric(data, "map", 0, "slam", "ate_rmse_m") == pytest.approx(0.0, abs=1e-9)
    assert metric(data, "map", 0, "slam", "n_sessions") == 1


def test_constant_offset_gives_that_ate_and_zero_after_alignment(tmp_path):
    gt = lawnmower()
    s0 = write_session(tmp_path / "s0", gt)
    loops_gt = write_loops_gt(tmp_path / "loops_gt.csv", [((0, 0), (0, 11))])
    shifted = [(x + 0.10, y, yaw) for x, y, yaw in gt]
    run = write_run(tmp_path / "run", {0: indexed(shifted)})
    m = evaluate_dirs(tmp_path, [s0], run, loops_gt=loops_gt)["session"]["0"]["odometry"]
    assert m["ate_rmse_m"] == pytest.approx(0.10, abs=1e-9)
    assert m["ate_aligned_rmse_m"] == pytest.approx(0.0, abs=1e-9)
    assert m["end_drift_pct"] == pytest.approx(100 * 0.10 / m["path_length_m"])
    assert m["rpe_trans_rmse_m"] == pytest.approx(0.0, abs=1e-9)  # relative motions unchanged
    assert m["ek_intra_m"] == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("scale,rotation", [(1.05, 0.0), (1.0, 0.2), (0.9, -0.1)])
def test_injected_scale_and_rotation_give_the_expected_end_drift(tmp_path, scale, rotation):
    length = 3.0
    gt = [(0.25 * i, 0.0, 0.0) for i in range(13)]  # straight, 3 m
    s0 = write_session(tmp_path / "s0", gt)
    est = [tuple(ev.compose(np.array([0.0, 0.0, rotation]), np.array([scale * x, 0.0, 0.0]))) for x, _, _ in gt]
    run = write_run(tmp_path / "run", {0: indexed(est)})
    m = evaluate_dirs(tmp_path, [s0], run)["session"]["0"]["odometry"]
    end = np.array([scale * length * math.cos(rotation), scale * length * math.sin(rotation)])
    expected = 100.0 * np.hypot(*(end - [length, 0.0])) / length
    assert m["end_drift_pct"] == pytest.approx(expected, rel=1e-9)
    if scale == 1.0:
        assert m["end_drift_pct"] == pytest.approx(200.0 * math.sin(abs(rotation) / 2))
        assert m["ate_aligned_rmse_m"] == pytest.approx(0.0, abs=1e-9)
    else:
        assert m["ate_aligned_rmse_m"] > 0.01  # no scale in the alignment


def test_only_keyframes_are_scored_and_rpe_is_between_consecutive_keyframes(tmp_path):
    gt = [(0.1 * i, 0.0, 0.0) for i in range(10)]
    s0 = write_session(tmp_path / "s0", gt)
    keyframes = [0, 3, 6, 9]
    est = {i: (gt[i][0] * 1.1, 0.0, 0.0) for i in keyframes}  # each 0.3 m step estimated as 0.33 m
    run = write_run(tmp_path / "run", {0: sorted(est.items())})
    m = evaluate_dirs(tmp_path, [s0], run)["session"]["0"]["odometry"]
    assert m["n_keyframes"] == 4
    assert m["rpe_trans_rmse_m"] == pytest.approx(0.03)
    assert m["path_length_m"] == pytest.approx(0.9)
    assert m["end_drift_pct"] == pytest.approx(10.0)


TURN = 2 * math.pi - 6.2  # 0.083 rad


@pytest.mark.parametrize("gt_yaws,est_yaws,error", [
    ((3.1, -3.1), (3.1, 3.1 + TURN + 0.01), 0.01),  # both turn +0.083 across pi, one unwrapped
    ((0.0, 3.1), (0.0, -3.1), TURN),                # turns of +3.1 and -3.1 differ by 0.083, not 6.2
    ((0.0, -3.1), (0.0, 3.1), TURN),
])
def test_rpe_wraps_yaw_differences(tmp_path, gt_yaws, est_yaws, error):
    gt = [(0.0, 0.0, gt_yaws[0]), (0.1, 0.0, gt_yaws[1])]
    est = [(0.0, 0.0, est_yaws[0]), (0.1, 0.0, est_yaws[1])]
    s0 = write_session(tmp_path / "s0", gt)
    run = write_run(tmp_path / "run", {0: indexed(est)})
    m = evaluate_dirs(tmp_path, [s0], run)["session"]["0"]["odometry"]
    assert m["rpe_rot_rmse_deg"] == pytest.approx(math.degrees(error), rel=1e-6)


def test_session_split_into_two_maps_is_scored_in_each_map_frame(tmp_path):
    # Tracking lost after frame 5: frames 6..11 start map 1 at its own origin.
    gt = lawnmower()
    s0 = write_session(tmp_path / "s0", gt)
    piece = in_frame(gt[6], gt[6:])
    trajectory = {0: [(i, 0, gt[i]) for i in range(6)] + [(i + 6, 1, p) for i, p in enumerate(piece)]}
    loops_gt = write_loops_gt(tmp_path / "loops_gt.csv", [((0, 0), (0, 5)), ((0, 0), (0, 11)), ((0, 6), (0, 11))])
    run = write_run(tmp_path / "run", {0: indexed(gt)}, trajectory)
    data = evaluate_dirs(tmp_path, [s0], run, loops_gt=loops_gt)
    m = data["session"]["0"]["slam"]
    assert m["ate_rmse_m"] == pytest.approx(0.0, abs=1e-9)
    assert m["rpe_trans_rmse_m"] == pytest.approx(0.0, abs=1e-9)  # the pair 5-6 spans two maps: skipped
    assert m["ek_intra_pairs"] == 2  # (0, 11) spans two maps: skipped
    assert metric(data, "map", 1, "slam", "n_keyframes") == 6
    assert metric(data, "map", 1, "slam", "ate_rmse_m") == pytest.approx(0.0, abs=1e-9)


def two_session_world():
    """Two sessions in a world frame that is neither session's frame (both turned and moved)."""
    local0 = lawnmower(10)
    local1 = [(0.15 * i, 0.05 * i, 0.0) for i in range(8)]
    world0 = to_world((5.0, -2.0, 0.7), local0)
    world1 = to_world((5.1, -1.9, -2.0), local1)
    return local0, local1, world0, world1


def test_two_session_map_with_world_gt_scores_an_injected_offset(tmp_path):
    local0, local1, world0, world1 = two_session_world()
    s0 = write_session(tmp_path / "s0", local0)
    s1 = write_session(tmp_path / "s1", local1)
    world = write_world_gt(tmp_path / "world_gt.csv", [world0, world1])
    inter = [((0, 0), (1, 0)), ((0, 5), (1, 3)), ((1, 7), (0, 9))]
    loops_gt = write_loops_gt(tmp_path / "loops_gt.csv", inter + [((0, 0), (0, 9)), ((1, 0), (1, 7))])
    # SLAM: s0 exact in the map frame (= s0's frame), s1 in that frame but shifted by (0.3, -0.4).
    map0 = in_frame(world0[0], world0)
    map1 = [(x + 0.3, y - 0.4, yaw) for x, y, yaw in in_frame(world0[0], world1)]
    trajectory = {0: [(i, 0, p) for i, p in indexed(map0)], 1: [(i, 0, p) for i, p in indexed(map1)]}
    run = write_run(tmp_path / "run", {0: indexed(local0), 1: indexed(local1)}, trajectory)
    data = evaluate_dirs(tmp_path, [s0, s1], run, world=world, loops_gt=loops_gt)

    m = data["map"]["0"]["slam"]
    assert m["n_sessions"] == 2 and m["n_keyframes"] == 18
    assert m["ate_rmse_m"] == pytest.approx(0.5 * math.sqrt(8 / 18))
    assert m["ek_inter_m"] == pytest.approx(0.5)  # |rotated offset| for every inter pair
    assert m["ek_inter_pairs"] == 3
    assert m["ek_intra_m"] == pytest.approx(0.0, abs=1e-9)
    assert m["ek_intra_pairs"] == 2
    s1_slam = data["session"]["1"]["slam"]
    assert s1_slam["ate_rmse_m"] == pytest.approx(0.5)
    assert s1_slam["ate_aligned_rmse_m"] == pytest.approx(0.0, abs=1e-9)
    assert s1_slam["ek_inter_m"] == pytest.approx(0.5) and s1_slam["ek_inter_pairs"] == 3
    assert data["session"]["0"]["slam"]["ate_rmse_m"] == pytest.approx(0.0, abs=1e-9)
    # Odometry is exact in each session's own frame; it has no inter-session e_k.
    assert data["session"]["1"]["odometry"]["ate_rmse_m"] == pytest.approx(0.0, abs=1e-9)
    assert "ek_inter_m" not in data["session"]["1"]["odometry"]


def test_two_session_map_without_world_gt_reports_na(tmp_path):
    local0, local1, world0, world1 = two_session_world()
    s0 = write_session(tmp_path / "s0", local0)
    s1 = write_session(tmp_path / "s1", local1)
    loops_gt = write_loops_gt(tmp_path / "loops_gt.csv", [((0, 0), (1, 0)), ((1, 0), (1, 7))])
    map1 = in_frame(world0[0], world1)
    trajectory = {0: [(i, 0, p) for i, p in indexed(local0)], 1: [(i, 0, p) for i, p in indexed(map1)]}
    run = write_run(tmp_path / "run", {0: indexed(local0), 1: indexed(local1)}, trajectory)
    data = evaluate_dirs(tmp_path, [s0, s1], run, loops_gt=loops_gt)
    assert metric(data, "map", 0, "slam", "ate_rmse_m") is None
    assert metric(data, "map", 0, "slam", "ek_inter_m") is None
    assert metric(data, "map", 0, "slam", "ek_inter_pairs") == 0
    # Relative metrics within a session still work from gt.csv.
    assert metric(data, "session", 1, "slam", "ek_intra_m") == pytest.approx(0.0, abs=1e-9)
    assert metric(data, "session", 1, "slam", "rpe_trans_rmse_m") == pytest.approx(0.0, abs=1e-9)
    notes = (tmp_path / "report" / "metrics.md").read_text()
    assert "world_gt.csv" in notes


def test_separate_maps_use_each_session_frame(tmp_path):
    local0, local1, _, _ = two_session_world()
    s0 = write_session(tmp_path / "s0", local0)
    s1 = write_session(tmp_path / "s1", local1)
    trajectory = {0: [(i, 0, p) for i, p in indexed(local0)], 1: [(i, 1, p) for i, p in indexed(local1)]}
    run = write_run(tmp_path / "run", {0: indexed(local0), 1: indexed(local1)}, trajectory)
    data = evaluate_dirs(tmp_path, [s0, s1], run)  # no world gt needed
    for map_id in (0, 1):
        assert metric(data, "map", map_id, "slam", "ate_rmse_m") == pytest.approx(0.0, abs=1e-9)
        assert metric(data, "map", map_id, "slam", "n_sessions") == 1


# ---------------------------------------------------------------------------------------------
# Loops.

def loop_scene(tmp_path, with_world=True):
    """Session 0 goes out along x and comes back 0.05 m lower; session 1 repeats the outward leg
    0.1 m lower in the world. Frames 0.2 m apart; footprint height 0.48 m."""
    out = [(0.2 * i, 0.0, 0.0) for i in range(6)]
    back = [(0.2 * (5 - i), 0.05, math.pi) for i in range(6)]
    local0 = out + back
    local1 = [(0.2 * i, 0.0, 0.0) for i in range(6)]
    s0 = write_session(tmp_path / "s0", local0)
    s1 = write_session(tmp_path / "s1", local1)
    world = write_world_gt(tmp_path / "world_gt.csv", [local0, [(x, 0.1, 0.0) for x, _, _ in local1]])
    return s0, s1, (world if with_world else None), local0, local1


def test_loop_precision_and_recall_with_planted_false_loops(tmp_path):
    s0, s1, world, local0, local1 = loop_scene(tmp_path)
    # Revisits: 0/i with 0/(11-i) are the same place.
    intra_gt = [((0, i), (0, 11 - i)) for i in range(5)]
    inter_gt = [((0, i), (1, i)) for i in range(4)]
    loops_gt = write_loops_gt(tmp_path / "loops_gt.csv", intra_gt + inter_gt)
    keyframes = [i for i in range(12) if i != 7]  # gt pair (0,4)-(0,7) cannot be found
    accepted = intra_gt[:3] + [((0, 8), (0, 3))]  # 4 true (one given reversed) ...
    accepted += [((0, 0), (0, 5))]                  # ... and one planted false: 1.0 m apart
    accepted += [((1, 1), (0, 1)), ((0, 2), (1, 2)), ((0, 0), (1, 5))]  # 2 true, 1 false inter
    run = write_run(tmp_path / "run", {0: indexed(local0, keyframes), 1: indexed(local1)}, loops=accepted)
    data = evaluate_dirs(tmp_path, [s0, s1], run, world=world, loops_gt=loops_gt)
    intra, inter, both = (data["loops"][k]["loops"] for k in ("intra", "inter", "all"))
    assert intra["accepted"] == 5 and intra["correct"] == 4
    assert intra["precision"] == pytest.approx(4 / 5)
    assert intra["gt_pairs"] == 5 and intra["gt_pairs_keyframes"] == 4
    assert intra["found"] == 4 and intra["recall"] == pytest.approx(1.0)
    assert inter["accepted"] == 3 and inter["precision"] == pytest.approx(2 / 3)
    assert inter["gt_pairs"] == 4 and inter["found"] == 2 and inter["recall"] == pytest.approx(0.5)
    assert both["precision"] == pytest.approx(6 / 8) and both["recall"] == pytest.approx(6 / 8)


def write_loop_poses(run, rows):
    """loop_poses.csv: rows of ((s, i), (s, i), measured pose of b in a)."""
    write_csv(os.path.join(run, "loop_poses.csv"), "session_a,index_a,session_b,index_b,x_m,y_m,yaw_rad",
              [(a[0], a[1], b[0], b[1]) + tuple(z) for a, b, z in rows])


def test_recall_over_all_pairs_finds_a_pair_through_keyframes_within_one_frame(tmp_path):
    # Out along x for 8 frames, then back along a line 0.2 m below: frame i revisits frame 15 - i.
    gt = [(0.1 * i, 0.0, 0.0) for i in range(8)] + [(0.1 * (15 - i), 0.2, math.pi) for i in range(8, 16)]
    s0 = write_session(tmp_path / "s0", gt)
    pairs = [((0, 2), (0, 13)), ((0, 3), (0, 12)), ((0, 4), (0, 11)), ((0, 5), (0, 10)), ((0, 6), (0, 9))]
    loops_gt = write_loops_gt(tmp_path / "loops_gt.csv", pairs)
    keyframes = [0, 2, 4, 6, 7, 9, 11, 13, 15]  # frames 3, 5, 10, 12 never became keyframes
    accepted = [((0, 2), (0, 13)),  # a pair itself; within one frame also of (3, 12)
                ((0, 11), (0, 4)),  # given reversed; within one frame of (5, 10) too
                ((0, 7), (0, 9))]   # 7 is one frame from 6: (6, 9) found
    run = write_run(tmp_path / "run", {0: indexed(gt, keyframes)}, loops=accepted)
    m = evaluate_dirs(tmp_path, [s0], run, loops_gt=loops_gt)["loops"]["intra"]["loops"]
    assert m["gt_pairs"] == 5 and m["gt_pairs_keyframes"] == 3  # (2,13), (4,11), (6,9)
    assert m["found"] == 2 and m["recall"] == pytest.approx(2 / 3)  # (7, 9) is not a keyframe pair of the gt
    assert m["found_near"] == 5 and m["recall_all"] == pytest.approx(1.0)
    # Two frames away is not near: a loop (0, 15) is near no pair; a loop (2, 11) is near none of
    # (2, 13) and (4, 11) but finds (3, 12) (one frame from each).
    run = write_run(tmp_path / "run2", {0: indexed(gt, keyframes)}, loops=[((0, 0), (0, 15)), ((0, 2), (0, 11))])
    m = evaluate_dirs(tmp_path / "b", [s0], run, loops_gt=loops_gt)["loops"]["intra"]["loops"]
    assert m["found_near"] == 1 and m["recall_all"] == pytest.approx(1 / 5)
    # A loop whose measured pose is wrong finds nothing, even next to a pair (loop_poses.csv).
    run = write_run(tmp_path / "run3", {0: indexed(gt, keyframes)}, loops=[((0, 2), (0, 13)), ((0, 4), (0, 11))])
    write_loop_poses(run, [((0, 2), (0, 13), ev.relative(np.array(gt[2]), np.array(gt[13]))),
                           ((0, 4), (0, 11), (0.5, 0.5, 0.0))])
    m = evaluate_dirs(tmp_path / "c", [s0], run, loops_gt=loops_gt)["loops"]["intra"]["loops"]
    assert m["precision"] == pytest.approx(0.5)
    assert m["found_near"] == 2 and m["recall_all"] == pytest.approx(2 / 5)  # (2,13) and (3,12); not (4,11), (5,10)


def test_recall_over_all_pairs_needs_the_same_sessions(tmp_path):
    s0, s1, world, local0, local1 = loop_scene(tmp_path)
    loops_gt = write_loops_gt(tmp_path / "loops_gt.csv", [((0, 1), (1, 1))])
    run = write_run(tmp_path / "run", {0: indexed(local0), 1: indexed(local1)}, loops=[((0, 1), (0, 2))])
    m = evaluate_dirs(tmp_path, [s0, s1], run, world=world, loops_gt=loops_gt)["loops"]["all"]["loops"]
    assert m["found_near"] == 0 and m["recall_all"] == 0.0  # (0,1)-(0,2) is within one index of (0,1)-(1,1)'s indexes only


def test_a_kink_is_the_largest_step_beyond_the_ground_truths(tmp_path):
    # A smooth line of 0.3 m steps; the estimate jumps 1 m sideways between frames 5 and 6 and
    # turns 10 degrees there (the rest follows, shifted).
    gt = [(0.0, 0.3 * i, 0.0) for i in range(10)]
    est = [(0.0 if i < 6 else 1.0, 0.3 * i, 0.0 if i < 6 else math.radians(10)) for i in range(10)]
    s0 = write_session(tmp_path / "s0", gt)
    run = write_run(tmp_path / "run", {0: indexed(est)}, {0: [(i, 0, p) for i, p in indexed(gt)]})
    data = evaluate_dirs(tmp_path, [s0], run)["session"]["0"]
    m = data["odometry"]
    assert m["max_step_gt_m"] == pytest.approx(0.3)
    assert m["max_step_m"] == pytest.approx(math.hypot(1.0, 0.3))
    assert m["max_step_excess_m"] == pytest.approx(math.hypot(1.0, 0.3) - 0.3)
    assert m["max_step_err_m"] == pytest.approx(1.0) and m["max_step_err_index"] == 6
    assert m["max_turn_deg"] == pytest.approx(10.0) and m["max_turn_gt_deg"] == pytest.approx(0.0, abs=1e-9)
    assert m["max_turn_err_deg"] == pytest.approx(10.0)
    s = data["slam"]  # the slam estimate is the ground truth: no kink
    assert s["max_step_excess_m"] == pytest.approx(0.0, abs=1e-12) and s["max_step_err_m"] == pytest.approx(0.0, abs=1e-12)
    text = (tmp_path / "report" / "metrics.md").read_text()
    assert "## Steps between consecutive keyframes (kinks)" in text and "| 1.000 | 6 |" in text


def test_similarity_alignment_removes_scale_rotation_and_offset(tmp_path):
    gt = lawnmower()
    s0 = write_session(tmp_path / "s0", gt)
    # An SfM-like estimate: scaled by 0.37, turned by 1 rad, moved; yaw turns with it.
    est = [tuple(ev.compose(np.array([3.0, -1.0, 1.0]), np.array([0.37 * x, 0.37 * y, yaw]))) for x, y, yaw in gt]
    run = write_run(tmp_path / "run", {0: indexed(est)})
    m = evaluate_dirs(tmp_path, [s0], run)["session"]["0"]["odometry"]
    assert m["ate_sim_rmse_m"] == pytest.approx(0.0, abs=1e-9)
    assert m["sim_scale"] == pytest.approx(1 / 0.37)
    assert m["ate_aligned_rmse_m"] > 0.1  # a rigid alignment cannot undo the scale
    # With noise on one keyframe the alignment is the least-squares optimum: any other scale or
    # rotation (with its best translation) leaves more, and the metric is that optimum's RMSE.
    noisy = list(est)
    noisy[3] = (noisy[3][0] + 0.05, noisy[3][1], noisy[3][2])
    run = write_run(tmp_path / "run2", {0: indexed(noisy)})
    m = evaluate_dirs(tmp_path / "b", [s0], run)["session"]["0"]["odometry"]
    e, g = np.array([p[:2] for p in noisy]), np.array([p[:2] for p in gt])

    def residual(scale, yaw):
        moved = scale * ev.rotate_rows(e, yaw)
        return float(np.sqrt(np.mean(np.sum((moved - moved.mean(axis=0) - g + g.mean(axis=0)) ** 2, axis=1))))

    scale, yaw, _ = ev.align_sim2(e, g)
    assert m["ate_sim_rmse_m"] == pytest.approx(residual(scale, yaw))
    assert 0 < m["ate_sim_rmse_m"] < 0.05 / 0.37
    for ds, dy in ((0.01, 0), (-0.01, 0), (0, 0.01), (0, -0.01)):
        assert residual(scale * (1 + ds), yaw + dy) > m["ate_sim_rmse_m"]


def test_default_true_loop_distance_is_the_footprint_height(tmp_path):
    s0, s1, world, local0, local1 = loop_scene(tmp_path)
    accepted = [((0, 0), (0, 2)), ((0, 0), (0, 3))]  # 0.4 m (overlap) and 0.6 m (no overlap) apart
    run = write_run(tmp_path / "run", {0: indexed(local0)}, loops=accepted)
    data = evaluate_dirs(tmp_path, [s0], run)
    assert data["loops"]["intra"]["loops"]["correct"] == 1
    data = evaluate_dirs(tmp_path, [s0], run, extra=["--loop-true-dist", "0.7"])
    assert data["loops"]["intra"]["loops"]["correct"] == 2
    assert data["loops"]["intra"]["loops"]["recall"] is None  # no loops_gt.csv


def test_inter_session_precision_is_na_without_world_gt(tmp_path):
    s0, s1, _, local0, local1 = loop_scene(tmp_path, with_world=False)
    accepted = [((0, 0), (0, 11)), ((0, 1), (1, 1))]
    loops_gt = write_loops_gt(tmp_path / "loops_gt.csv", [((0, 1), (1, 1))])
    run = write_run(tmp_path / "run", {0: indexed(local0), 1: indexed(local1)}, loops=accepted)
    data = evaluate_dirs(tmp_path, [s0, s1], run, loops_gt=loops_gt)
    assert data["loops"]["intra"]["loops"]["precision"] == pytest.approx(1.0)
    assert data["loops"]["inter"]["loops"]["precision"] is None
    assert data["loops"]["inter"]["loops"]["recall"] == pytest.approx(1.0)  # recall needs no world gt


def test_header_only_loops_and_missing_trajectory(tmp_path):
    s0, _, _, local0, _ = loop_scene(tmp_path)
    loops_gt = write_loops_gt(tmp_path / "loops_gt.csv", [((0, 0), (0, 11))])
    run = write_run(tmp_path / "run", {0: indexed(local0)}, loops=[])
    data = evaluate_dirs(tmp_path, [s0], run, loops_gt=loops_gt)
    m = data["loops"]["intra"]["loops"]
    assert m["accepted"] == 0 and m["precision"] is None and m["recall"] == 0.0
    assert "map" not in data and list(data["session"]["0"]) == ["odometry"]


def test_a_spreadsheets_byte_order_mark_is_not_part_of_the_header(tmp_path):
    """gt.csv and frames.csv saved by a spreadsheet as "CSV UTF-8" start with a byte-order mark:
    read as without it (same metrics)."""
    gt = lawnmower()
    plain = write_session(tmp_path / "plain", gt)
    marked = write_session(tmp_path / "marked", gt)
    for name in ("gt.csv", "frames.csv"):
        path = os.path.join(marked, name)
        with open(path, "rb") as f:
            data = f.read()
        with open(path, "wb") as f:
            f.write(b"\xef\xbb\xbf" + data)
    drift = [0.01 * i for i in range(len(gt))]
    est = [(x + d, y, yaw) for (x, y, yaw), d in zip(gt, drift)]
    a = evaluate_dirs(tmp_path / "a", [plain], write_run(tmp_path / "run_a", {0: indexed(est)}))
    b = evaluate_dirs(tmp_path / "b", [marked], write_run(tmp_path / "run_b", {0: indexed(est)}))
    assert a["session"]["0"]["odometry"] == b["session"]["0"]["odometry"]
    assert a["session"]["0"]["odometry"]["ate_rmse_m"] > 0


def test_a_zero_byte_output_is_refused_not_read_as_empty(tmp_path, capsys):
    """A header alone is an empty result (above); a file without even a header was cut off before
    its first line (a full disk, a killed run): refused, naming it, instead of scored as if the
    run had produced nothing (a zero-byte trajectory.csv dropped every slam metric silently)."""
    s0, _, _, local0, _ = loop_scene(tmp_path)
    for name in ("trajectory.csv", "loops.csv"):
        run = write_run(tmp_path / ("run_" + name), {0: indexed(local0)}, loops=[])
        open(os.path.join(run, name), "wb").close()  # zero bytes
        assert run_main(["--run", run, "--report", tmp_path / "report", "--no-plots", "--session", s0]) == 1
        assert "%s: empty file, not even a header" % name in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------
# Outputs and the command line.

def test_report_files_agree_and_timing_is_copied(tmp_path, capsys):
    gt = lawnmower()
    s0 = write_session(tmp_path / "s0", gt)
    run = write_run(tmp_path / "run", {0: indexed(gt)}, {0: [(i, 0, p) for i, p in indexed(gt)]},
                    loops=[], timing=[("odometry", 12, 240.0, 20.0, 31.5)])
    data = evaluate_dirs(tmp_path, [s0], run)
    with open(tmp_path / "report" / "metrics.csv") as f:
        rows = list(csv.DictReader(f))
    assert rows and set(rows[0]) == {"scope", "id", "estimate", "metric", "value"}
    for row in rows:
        value = data[row["scope"]][row["id"]][row["estimate"]][row["metric"]]
        assert row["value"] == "n/a" if value is None else float(row["value"]) == pytest.approx(value)
    assert data["timing"]["odometry"]["timing"] == {"calls": 12, "total_ms": 240.0, "mean_ms": 20.0,
                                                    "max_ms": 31.5}
    md = (tmp_path / "report" / "metrics.md").read_text()
    for title in ("## Sessions", "## Maps (slam)", "## Loops", "## Timing"):
        assert title in md
    assert "## Sessions" in capsys.readouterr().out


def two_session_folders(tmp_path):
    """two_session_world's folders, world_gt.csv and an exact SLAM trajectory (both in map 0)."""
    local0, local1, world0, world1 = two_session_world()
    s0 = write_session(tmp_path / "s0", local0)
    s1 = write_session(tmp_path / "s1", local1)
    world = write_world_gt(tmp_path / "world_gt.csv", [world0, world1])
    trajectory = {0: [(i, 0, p) for i, p in indexed(in_frame(world0[0], world0))],
                  1: [(i, 0, p) for i, p in indexed(in_frame(world0[0], world1))]}
    return s0, s1, world, trajectory, local0, local1


def is_png(path):
    with open(path, "rb") as f:
        return f.read(8) == b"\x89PNG\r\n\x1a\n"


def test_plots_are_written_unless_disabled(tmp_path):
    s0, s1, world, trajectory, local0, local1 = two_session_folders(tmp_path)
    run = write_run(tmp_path / "run", {0: indexed(local0), 1: indexed(local1)}, trajectory,
                    loops=[((0, 0), (1, 0)), ((0, 0), (0, 9))])
    base = ["--run", run, "--session", s0, "--session", s1, "--world-gt", world]
    assert run_main(base + ["--report", tmp_path / "quiet", "--no-plots"]) == 0
    assert not [n for n in os.listdir(tmp_path / "quiet") if n.endswith(".png")]
    assert run_main(base + ["--report", tmp_path / "plots"]) == 0
    pngs = sorted(n for n in os.listdir(tmp_path / "plots") if n.endswith(".png"))
    assert pngs == ["map_0.png", "session_0.png", "session_1.png"]
    assert all(is_png(tmp_path / "plots" / n) for n in pngs)


def figure_inputs(tmp_path, odometry_scale=1.0):
    """Two sessions joined in map 0 (links.csv), one correct and one wrong loop; the odometry of
    session 1 scaled by `odometry_scale` (a drift no rigid motion removes)."""
    s0, s1, world, trajectory, local0, local1 = two_session_folders(tmp_path)
    odo1 = [(odometry_scale * x, odometry_scale * y, yaw) for x, y, yaw in local1]
    # (0,0)-(1,0) are near each other in the world (a correct loop); (0,9)-(1,0) are not.
    run = write_run(tmp_path / "run", {0: indexed(local0), 1: indexed(odo1)}, trajectory,
                    loops=[((0, 0), (1, 0)), ((0, 9), (1, 0))])
    write_csv(os.path.join(run, "links.csv"), "map,previous_session,current_session,loops,x_m,y_m,yaw_rad",
              [(0, 0, 1, 1, 0.0, 0.0, 0.0)])
    gt = ev.load_ground_truth([s0, s1], world)
    loaded = ev.load_run(run)
    return ev.evaluate(loaded, gt, 0.3), loaded, gt


def layers_of(layers, kind):
    return [layer for layer in layers if layer.kind == kind]


def test_map_figure_colours_sessions_and_draws_odometry_under_slam_loops_and_join_links(tmp_path):
    evaluation, run, _ = figure_inputs(tmp_path, odometry_scale=1.1)
    layers = ev.map_layers(evaluation, run, 0)
    slam, odometry = layers_of(layers, "slam"), layers_of(layers, "odometry")
    assert [layer.label for layer in slam] == ["SLAM s0", "SLAM s1"]
    assert len({layer.colour for layer in slam}) == 2  # each session its own colour
    for s, o in zip(slam, odometry):
        assert o.colour == s.colour and o.style == "--" and s.style == "-" and o.zorder < s.zorder
        # The odometry starts where the SLAM puts the session's first keyframe.
        np.testing.assert_allclose(o.segments[0][0], s.segments[0][0], atol=1e-12)
    # Session 1's odometry drifts off its SLAM by the injected scale: 10 % of its 1.1 m path.
    drift = np.linalg.norm(odometry[1].segments[0][-1] - slam[1].segments[0][-1])
    assert drift == pytest.approx(0.1 * math.hypot(0.15 * 7, 0.05 * 7), rel=1e-9)
    np.testing.assert_allclose(odometry[0].segments[0], slam[0].segments[0], atol=1e-9)
    # Loops in two colours by verdict; the join link from s0's last keyframe to s1's first.
    assert [(layer.kind, len(layer.segments)) for layer in layers if layer.kind.startswith("loop")] == [
        ("loop_wrong", 1), ("loop_correct", 1)]
    assert layers_of(layers, "loop_correct")[0].colour != layers_of(layers, "loop_wrong")[0].colour
    link, = layers_of(layers, "join_link")
    np.testing.assert_allclose(link.segments[0], [slam[0].segments[0][-1], slam[1].segments[0][0]], atol=1e-12)


def test_a_long_thin_map_gets_a_stretched_second_view(tmp_path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    thin = [ev.Layer("slam", "SLAM s0", [np.array([[0.03 * i, 0.1 * (i % 2)] for i in range(101)])], "tab:blue",
                     "-", 1.0, 3)]
    square = [ev.Layer("slam", "SLAM s0", [np.array([[0, 0], [3, 0], [3, 2.5], [0, 2.5]])], "tab:blue", "-", 1.0, 3)]
    assert ev.is_thin(thin) and not ev.is_thin(square)  # 3 m x 0.1 m against 3 m x 2.5 m
    assert ev.render(plt, thin, "thin", str(tmp_path / "thin.png")) == 2
    assert ev.render(plt, square, "square", str(tmp_path / "square.png")) == 1
    assert is_png(tmp_path / "thin.png") and is_png(tmp_path / "square.png")


def test_html_report_is_one_self_contained_file_with_tables_figures_and_configuration(tmp_path):
    import base64
    import re
    evaluation, run, _ = figure_inputs(tmp_path)
    with open(os.path.join(tmp_path / "run", "config.yaml"), "w") as f:
        f.write("backend:\n  join_min_loops: 7  # <marker>\n")
    base = ["--run", tmp_path / "run", "--session", tmp_path / "s0", "--session", tmp_path / "s1", "--world-gt",
            tmp_path / "world_gt.csv", "--loop-true-dist", "0.3"]
    assert run_main(base + ["--report", tmp_path / "r"]) == 0
    assert not os.path.exists(tmp_path / "r" / "report.html")  # only with --html
    assert run_main(base + ["--report", tmp_path / "r", "--html"]) == 0
    page = (tmp_path / "r" / "report.html").read_text()
    # Nothing outside the file: every src/href is a data: URI.
    assert re.findall(r'(?:src|href)="(?!data:)', page) == []
    # Each figure embedded, byte for byte.
    images = re.findall(r'src="data:image/png;base64,([^"]+)"', page)
    pngs = sorted(n for n in os.listdir(tmp_path / "r") if n.endswith(".png"))
    assert sorted(base64.b64decode(i) for i in images) == sorted((tmp_path / "r" / n).read_bytes() for n in pngs)
    assert len(images) == 3
    # The tables of metrics.md, with their values: the map's ATE as the markdown prints it.
    md = (tmp_path / "r" / "metrics.md").read_text()
    assert page.count("<table>") == sum(line.startswith("|---") for line in md.splitlines())
    assert "<h2>Inputs</h2>" not in page  # this run has no inputs.csv
    map_ate = ev.md_value(json.loads((tmp_path / "r" / "metrics.json").read_text())["map"]["0"]["slam"]["ate_rmse_m"])
    assert "<td>%s</td>" % map_ate in page
    # The configuration, escaped.
    assert "join_min_loops: 7  # &lt;marker&gt;" in page


def test_links_planted_in_the_report_are_replaced_never_written_through(tmp_path):
    """Every report file is written by atomic_file.py: a link at a final name (metrics.json, a plot) or
    at a temporary name (report.html.tmp, metrics.csv.tmp) leaves the files it points to untouched."""
    figure_inputs(tmp_path)
    outside, report = tmp_path / "outside", tmp_path / "r"
    outside.mkdir()
    report.mkdir()
    planted = ["metrics.json", "metrics.md", "map_0.png", "report.html.tmp", "metrics.csv.tmp", "session_0.png.tmp"]
    for n, name in enumerate(planted):
        (outside / name).write_text("precious %d\n" % n)
        (report / name).symlink_to(outside / name)
    (report / "metrics.csv.tmp.dangling").symlink_to(outside / "created")
    base = ["--run", tmp_path / "run", "--session", tmp_path / "s0", "--session", tmp_path / "s1", "--world-gt",
            tmp_path / "world_gt.csv", "--report", report, "--html"]
    assert run_main(base) == 0
    assert run_main(base[:-3] + ["--report", tmp_path / "clean", "--no-plots"]) == 0
    assert sorted(os.listdir(outside)) == sorted(planted)  # nothing created outside
    for n, name in enumerate(planted):
        assert (outside / name).read_text() == "precious %d\n" % n, name
    for name in ("metrics.json", "metrics.md", "map_0.png"):
        assert not (report / name).is_symlink() and (report / name).is_file(), name
    for name in ("metrics.json", "metrics.md", "metrics.csv"):
        assert (report / name).read_text() == (tmp_path / "clean" / name).read_text(), name
    assert is_png(report / "map_0.png") and is_png(report / "session_0.png")
    assert (report / "report.html.tmp").is_symlink()  # not the writer's: left as it was
    assert "<html>" in (report / "report.html").read_text()


def test_a_folder_split_by_tracking_loss_is_scored_and_drawn_per_piece(tmp_path):
    """pieces.csv (offline_slam): folder 0 in two pieces, frames 0-5 and 8-11, each piece's odometry
    exact in its own frame (restarting at the origin), the SLAM exact in one map joined by a link."""
    poses = lawnmower(12)
    s0 = write_session(tmp_path / "s0", poses)
    first, second = list(range(6)), list(range(8, 12))
    odometry = {0: [(i, p) for i, p in zip(first, in_frame(poses[0], [poses[i] for i in first]))] +
                [(i, p) for i, p in zip(second, in_frame(poses[8], [poses[i] for i in second]))]}
    trajectory = {0: [(i, 0, in_frame(poses[0], [poses[i]])[0]) for i in first + second]}
    run = write_run(tmp_path / "run", odometry, trajectory)
    base = ["--run", run, "--session", s0]
    # Without pieces.csv: one row, the second piece scored in the first piece's frame (metres off).
    assert run_main(base + ["--report", tmp_path / "whole", "--no-plots"]) == 0
    whole = json.loads((tmp_path / "whole" / "metrics.json").read_text())["session"]
    assert sorted(whole) == ["0"] and whole["0"]["odometry"]["ate_rmse_m"] > 0.3
    write_csv(os.path.join(run, "pieces.csv"), "session,piece,store_session,first_index,last_index,keyframes,map",
              [(0, 0, 0, 0, 5, 6, 0), (0, 1, 1, 8, 11, 4, 0)])
    write_csv(os.path.join(run, "links.csv"),
              "map,previous_session,current_session,loops,x_m,y_m,yaw_rad,previous_piece,current_piece",
              [(0, 0, 0, 3, 0.0, 0.0, 0.0, 0, 1)])
    assert run_main(base + ["--report", tmp_path / "pieces", "--no-plots"]) == 0
    scored = json.loads((tmp_path / "pieces" / "metrics.json").read_text())
    assert sorted(scored["session"]) == ["0.0", "0.1"]
    for name, n in (("0.0", 6), ("0.1", 4)):
        odo = scored["session"][name]["odometry"]
        assert odo["n_keyframes"] == n and odo["ate_rmse_m"] == pytest.approx(0.0, abs=1e-9)
    assert scored["map"]["0"]["slam"]["n_sessions"] == 2  # two pieces
    assert "split by tracking loss into 2 pieces" in (tmp_path / "pieces" / "metrics.md").read_text()
    # Drawn per piece: the odometry and SLAM lines broken between the pieces, each piece's odometry
    # on its SLAM, and the join link from piece 0's last keyframe to piece 1's first.
    loaded = ev.load_run(run)
    evaluation = ev.evaluate(loaded, ev.load_ground_truth([s0]))
    layers = ev.map_layers(evaluation, loaded, 0)
    (odo,), (slam,), (link,) = (layers_of(layers, kind) for kind in ("odometry", "slam", "join_link"))
    assert [len(seg) for seg in odo.segments] == [len(seg) for seg in slam.segments] == [6, 4]
    for o, s in zip(odo.segments, slam.segments):
        np.testing.assert_allclose(o, s, atol=1e-9)
    np.testing.assert_allclose(link.segments[0], [slam.segments[0][-1], slam.segments[1][0]], atol=1e-12)


def test_mission_folder_finds_sessions_and_truth_files(tmp_path):
    local0, local1, world0, world1 = two_session_world()
    mission = tmp_path / "mission"
    write_session(mission / "s0", local0)
    write_session(mission / "s1", local1)
    os.makedirs(mission / "notes")  # not a session: no frames.csv
    write_world_gt(mission / "world_gt.csv", [world0, world1])
    write_loops_gt(mission / "loops_gt.csv", [((0, 0), (1, 0))])
    map1 = [(x + 0.3, y - 0.4, yaw) for x, y, yaw in in_frame(world0[0], world1)]
    trajectory = {0: [(i, 0, p) for i, p in indexed(in_frame(world0[0], world0))],
                  1: [(i, 0, p) for i, p in indexed(map1)]}
    run = write_run(tmp_path / "run", {0: indexed(local0), 1: indexed(local1)}, trajectory)
    assert run_main(["--run", run, "--mission", mission, "--report", tmp_path / "r", "--no-plots"]) == 0
    data = json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert metric(data, "map", 0, "slam", "ek_inter_m") == pytest.approx(0.5)
    assert data["loops"]["inter"]["loops"]["gt_pairs"] == 1


def check_fails(capsys, args, words):
    code = run_main(args)
    err = capsys.readouterr().err
    assert code != 0
    assert len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err
    for word in words:
        assert word in err, err


def test_bad_input_exits_non_zero_with_one_line(tmp_path, capsys):
    gt = lawnmower()
    s0 = write_session(tmp_path / "s0", gt)
    run = write_run(tmp_path / "run", {0: indexed(gt), 1: indexed(gt)})
    report = ["--report", tmp_path / "report"]
    check_fails(capsys, ["--run", tmp_path / "nope", "--session", s0] + report, ["nope", "not found"])
    check_fails(capsys, ["--run", run, "--session", tmp_path / "missing"] + report, ["missing"])
    check_fails(capsys, ["--run", run, "--session", s0] + report, ["session 1", "1 ground-truth folder"])
    check_fails(capsys, ["--run", run] + report, ["--session"])  # no ground truth at all
    bad = tmp_path / "bad"
    os.makedirs(bad)
    write_csv(bad / "odometry.csv", "session,idx,x_m,y_m,yaw_rad", [(0, 0, 0.0, 0.0, 0.0)])
    check_fails(capsys, ["--run", bad, "--session", s0] + report, ["odometry.csv", "index"])
    os.remove(bad / "odometry.csv")
    check_fails(capsys, ["--run", bad, "--session", s0] + report, ["odometry.csv", "not found"])
    write_run(bad, {0: [(99, (0.0, 0.0, 0.0))]})
    check_fails(capsys, ["--run", bad, "--session", s0] + report, ["gt.csv", "99"])


ROS_CALIBRATION = """image_width: 240
image_height: 180
camera_name: down
camera_matrix: {rows: 3, cols: 3, data: [220, 0, 119.5, 0, 221, 89.5, 0, 0, 1]}
distortion_model: plumb_bob
distortion_coefficients: {rows: 1, cols: 5, data: [-0.1, 0.02, 0, 0, 0]}
rectification_matrix: {rows: 3, cols: 3, data: [1, 0, 0, 0, 1, 0, 0, 0, 1]}
projection_matrix: {rows: 3, cols: 4, data: [220, 0, 119.5, 0, 0, 221, 89.5, 0, 0, 0, 1, 0]}
"""


def test_camera_yaml_is_read_in_both_layouts_and_refused_by_key(tmp_path):
    """As core::readCameraYaml (doc/dataset_format.md): the six keys, or a ROS calibration YAML (K)."""
    path = tmp_path / "camera.yaml"

    def read(text):
        path.write_text(text)
        return ev.read_camera_yaml(str(path))

    want = {"image_width": 240, "image_height": 180, "fx": 220, "fy": 221, "cx": 119.5, "cy": 89.5}
    assert read(ROS_CALIBRATION) == want
    assert read("image_width: 240\nimage_height: 180\nfx: 2.2e2\nfy: 221  # comment\n"
                "cx: 119.5\ncy: 89.5\n") == want
    assert read(ROS_CALIBRATION.replace("plumb_bob", "rational_polynomial").replace(
        "cols: 5, data: [-0.1, 0.02, 0, 0, 0]", "cols: 8, data: [-0.1, 0.02, 0, 0, 0, 0, 0, 0]")) == want
    # Optional keys may be missing.
    assert read("\n".join(line for line in ROS_CALIBRATION.splitlines()
                          if not line.startswith(("rectification", "projection", "camera_name")))) == want
    for text, words in [
            (ROS_CALIBRATION.replace("distortion_model: plumb_bob\n", ""), ["missing key 'distortion_model'"]),
            (ROS_CALIBRATION.replace("plumb_bob", "equidistant"), ["distortion_model 'equidistant'"]),
            (ROS_CALIBRATION.replace("rows: 3, cols: 3, data: [220, 0, 119.5, 0, 221, 89.5, 0, 0, 1]",
                                     "rows: 3, cols: 3, data: [220, 0, 119.5]"), ["camera_matrix must be"]),
            (ROS_CALIBRATION.replace("cols: 5, data: [-0.1, 0.02, 0, 0, 0]", "cols: 3, data: [-0.1, 0.02, 0]"),
             ["distortion_coefficients", "4 or 5"]),
            (ROS_CALIBRATION.replace("image_width: 240", "image_width: 240.5"), ["image_width", "whole number"]),
            ("image_width: 240\nimage_height: 180\nfx: 220\nfy: 221\ncx: 119.5\n", ["missing key 'cy'"]),
            ("image_width: 240\nimage_height: 180\nfx: '220'\nfy: 221\ncx: 119.5\ncy: 89.5\n",
             ["fx", "'220' is quoted text"]),
            ("image_width: 240\nimage_height: 180\nfx: 0\nfy: 221\ncx: 119.5\ncy: 89.5\n", ["fx and fy"]),
            ("fx: [1,\n", ["not YAML"]), ("just text\n", ["expected 'key: value'"])]:
        with pytest.raises(ev.EvalError) as e:
            read(text)
        assert str(e.value).startswith(str(path) + ":") and all(w in str(e.value) for w in words), (str(e.value), words)


def test_command_line_process_has_help_and_clean_errors(tmp_path):
    done = subprocess.run(["/usr/bin/python3", TOOL, "--help"], capture_output=True, text=True)
    assert done.returncode == 0
    for word in ("--mission", "--loop-true-dist", "ate_aligned_rmse_m", "ek_inter_m", "recall"):
        assert word in done.stdout
    done = subprocess.run(["/usr/bin/python3", TOOL, "--run", str(tmp_path / "x"), "--session", str(tmp_path),
                           "--report", str(tmp_path / "r")], capture_output=True, text=True)
    assert done.returncode == 1
    assert "Traceback" not in done.stderr and len(done.stderr.strip().splitlines()) == 1


def test_measured_loop_poses_decide_correctness_and_nan_altitude_is_na(tmp_path):
    s0, _, _, local0, _ = loop_scene(tmp_path)
    # Two loops 0.4 m apart (the images overlap); loop_poses.csv says one was measured right and
    # one 0.3 m off (a geometrically wrong loop between overlapping images).
    accepted = [((0, 0), (0, 2)), ((0, 1), (0, 3))]
    run = write_run(tmp_path / "run", {0: indexed(local0)}, loops=accepted)
    write_csv(os.path.join(run, "loop_poses.csv"), "session_a,index_a,session_b,index_b,x_m,y_m,yaw_rad",
              [(0, 0, 0, 2, 0.4, 0.0, 0.0), (0, 1, 0, 3, 0.7, 0.0, 0.0)])
    data = evaluate_dirs(tmp_path, [s0], run)
    assert data["loops"]["intra"]["loops"]["accepted"] == 2 and data["loops"]["intra"]["loops"]["correct"] == 1
    # A NaN altitude on one frame: its partner's footprint still judges the loop; on both: n/a.
    gt = ev.load_ground_truth([s0])
    gt.sessions[0].altitude[0] = float("nan")
    assert ev.judge_loops(gt, [((0, 0), (0, 2))]) == {((0, 0), (0, 2)): True}
    gt.sessions[0].altitude[2] = float("nan")
    assert ev.judge_loops(gt, [((0, 0), (0, 2))]) == {((0, 0), (0, 2)): None}


# ---------------------------------------------------------------------------------------------
# The run must be the run of the folders given (a run of test1 had been scored against test2's folder).

def write_inputs(run, rows):
    """inputs.csv as offline_slam writes it: (session, folder, frames, first, last, mean altitude)."""
    write_csv(os.path.join(run, "inputs.csv"), "session,folder,frames,first_stamp_s,last_stamp_s,altitude_mean_m",
              rows)


def test_run_scored_against_another_folder_is_refused_with_the_reason(tmp_path, capsys):
    gt = lawnmower()
    s0 = write_session(tmp_path / "test1", gt)
    # test2: the same frame indexes and stamps (as the ACFR folders), other altitudes.
    other = write_session(tmp_path / "test2", gt)
    write_csv(os.path.join(other, "frames.csv"), "index,image,stamp_s,altitude_m",
              [(i, "%04d.png" % i, 0.5 * i, ALTITUDE + 0.01 * i) for i in range(len(gt))])
    run = write_run(tmp_path / "run", {0: indexed(gt)})
    write_inputs(run, [(0, s0, len(gt), 0.0, 0.5 * (len(gt) - 1), ALTITUDE)])
    report = ["--report", tmp_path / "report", "--no-plots"]
    assert run_main(["--run", run, "--session", s0] + report) == 0
    assert "inputs.csv" not in (tmp_path / "report" / "metrics.md").read_text()
    check_fails(capsys, ["--run", run, "--session", other] + report,
                ["session 0 of the run was made from %s" % s0, "12 frames, stamps 0.000..5.500 s, mean altitude 2.0000 m",
                 "but %s has 12 frames, stamps 0.000..5.500 s, mean altitude 2.0550 m" % other, "not the same folder"])
    # Other stamps or another frame count are refused the same way.
    for frames in ([(i, "%04d.png" % i, 10.0 + 0.5 * i, ALTITUDE) for i in range(len(gt))],
                   [(i, "%04d.png" % i, 0.5 * i, ALTITUDE) for i in range(len(gt) + 1)]):
        write_csv(os.path.join(other, "frames.csv"), "index,image,stamp_s,altitude_m", frames)
        check_fails(capsys, ["--run", run, "--session", other] + report, ["not the same folder"])


def test_session_count_must_match_the_folders(tmp_path, capsys):
    gt = lawnmower()
    s0 = write_session(tmp_path / "s0", gt)
    s1 = write_session(tmp_path / "s1", gt)
    run = write_run(tmp_path / "run", {0: indexed(gt)})
    report = ["--report", tmp_path / "report", "--no-plots"]
    check_fails(capsys, ["--run", run, "--session", s0, "--session", s1] + report,
                ["2 folder(s) given but the run has no keyframe of session(s) 1 (%s)" % s1])
    write_inputs(run, [(0, s0, len(gt), 0.0, 5.5, ALTITUDE), (1, s1, len(gt), 0.0, 5.5, ALTITUDE)])
    check_fails(capsys, ["--run", run, "--session", s0] + report,
                ["made from folder %s as session 1" % s1, "only 1 folder(s)"])


def test_run_without_inputs_csv_is_scored_with_a_note(tmp_path):
    gt = lawnmower()
    s0 = write_session(tmp_path / "s0", gt)
    run = write_run(tmp_path / "run", {0: indexed(gt)})
    evaluate_dirs(tmp_path, [s0], run)
    assert "no inputs.csv" in (tmp_path / "report" / "metrics.md").read_text()
