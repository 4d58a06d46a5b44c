"""scripts/bench_nav.py, the nav benchmark's scoring: which keyframes count as blind, the two ATEs
against a planted trajectory with known errors, and one tiny row end to end (its table line, its
verdict and exit status agreeing with the numbers)."""
import importlib.util
import math
import os
import subprocess
import sys

import pytest
import yaml
from tool_runner import BIN_DIR, make_survey, read_csv as rows

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.realpath(__file__))))
_spec = importlib.util.spec_from_file_location("bench_nav", os.path.join(REPO, "scripts", "bench_nav.py"))
bench_nav = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench_nav)

# A short out-and-back, 4 blank frames on the way out.
SURVEY = {
    "seed": 3,
    "world": {"width_m": 10, "height_m": 7, "featureless_fraction": 0},
    "sessions": [{
        "name": "a",
        "camera": {"image_width": 240, "image_height": 180, "fx": 220, "fy": 220, "cx": 119.5, "cy": 89.5},
        "mission": {"pattern": "out_and_back", "start_m": [3, 3], "length_m": 3.5, "leg_spacing_m": 0.6,
                    "speed_m_s": 0.4, "frame_period_s": 1.0, "altitude_m": 2.0},
        "water": {"stretches": [{"first_frame": 3, "num_frames": 4, "kind": "blank"}]},
        "nav": {"enabled": True},
    }],
}


def test_blind_frames_are_the_stretches_of_each_session():
    survey = {"sessions": [{"water": {"stretches": [{"first_frame": 2, "num_frames": 3}]}}, {},
                           {"water": {"stretches": [{"first_frame": 0, "num_frames": 1},
                                                    {"first_frame": 9, "num_frames": 2}]}}]}
    assert bench_nav.blind_frames(survey) == {(0, 2), (0, 3), (0, 4), (2, 0), (2, 9), (2, 10)}


def test_ate_splits_seen_and_blind_keyframes_in_the_map_frame(tmp_path):
    """A planted run: every keyframe of the ground truth (gt.csv is the map frame here: one session),
    the seen ones 3 mm off in x, the blind ones 40 mm off in y; one map."""
    mission = make_survey(tmp_path, yaml.safe_dump(SURVEY))
    blind = bench_nav.blind_frames(SURVEY)
    run = tmp_path / "run"
    run.mkdir()
    odo = ["session,index,x_m,y_m,yaw_rad"]
    traj = ["session,index,map,x_m,y_m,yaw_rad"]
    for g in rows(mission / "a" / "gt.csv"):
        i = int(g["index"])
        dx, dy = (0.0, 0.04) if (0, i) in blind else (0.003, 0.0)
        x, y, yaw = float(g["x_m"]) + dx, float(g["y_m"]) + dy, float(g["yaw_rad"])
        odo.append(f"0,{i},{x},{y},{yaw}")
        traj.append(f"0,{i},0,{x},{y},{yaw}")
    (run / "odometry.csv").write_text("\n".join(odo) + "\n")
    (run / "trajectory.csv").write_text("\n".join(traj) + "\n")
    seen, dark = bench_nav.ate(str(run), [str(mission / "a")], str(mission / "world_gt.csv"), blind)
    assert seen == pytest.approx(0.003, abs=2e-6) and dark == pytest.approx(0.04, abs=2e-6)
    # Without blind frames in the spec, the 40 mm keyframes count in the map ATE.
    seen_all, none = bench_nav.ate(str(run), [str(mission / "a")], str(mission / "world_gt.csv"), set())
    n_blind = len(blind)
    n = len(rows(mission / "a" / "gt.csv"))
    assert none is None
    assert seen_all == pytest.approx(math.sqrt(((n - n_blind) * 0.003 ** 2 + n_blind * 0.04 ** 2) / n), abs=2e-6)


def test_a_row_end_to_end(tmp_path):
    spec = tmp_path / "rows.yaml"
    spec.write_text(yaml.safe_dump({"rows": [{"name": "tiny", "survey": SURVEY}]}))
    r = subprocess.run([sys.executable, os.path.join(REPO, "scripts", "bench_nav.py"), "--bin", BIN_DIR, "--out",
                        tmp_path / "out", "--spec", spec], capture_output=True, text=True, timeout=600)
    line = [x for x in r.stdout.splitlines() if x.startswith("| tiny |")]
    assert len(line) == 1, r.stdout + r.stderr
    cells = [c.strip() for c in line[0].strip("|").split("|")]
    with_nav, without = float(cells[1]), float(cells[2])
    assert cells[4] != "n/a"  # the nav carried the blind frames into the map
    verdict = "PASS" if with_nav <= without + 5.0 else "FAIL"
    assert cells[-1] == verdict and r.returncode == (0 if verdict == "PASS" else 1), r.stdout + r.stderr
    assert (tmp_path / "out" / "tiny" / "on" / "report" / "metrics.csv").exists()  # evaluate.py's report
    r = subprocess.run([sys.executable, os.path.join(REPO, "scripts", "bench_nav.py"), "--bin", BIN_DIR, "--out",
                        tmp_path / "o2", "--spec", spec, "--rows", "tiny,nope"], capture_output=True, text=True)
    assert r.returncode == 2 and "unknown rows nope" in r.stderr


def test_a_piece_the_nav_placed_is_scored_in_its_own_frame_until_a_loop_ties_it(tmp_path):
    """A planted run: one folder in two pieces (a tracking loss at frame 5), both in one map because
    the nav placed the second 0.5 m off (no other error). The map ATE of the table scores each
    visual group (pieces tied by loops.csv) in its own frame: 0 while no loop ties the pieces, the
    0.5 m once one does; the one-frame ATE sees the 0.5 m either way; nav_placements.csv's row
    is scored against the ground truth's relative pose."""
    mission = make_survey(tmp_path, yaml.safe_dump(SURVEY))
    gt = rows(mission / "a" / "gt.csv")
    run = tmp_path / "run"
    run.mkdir()
    odo, traj = ["session,index,x_m,y_m,yaw_rad"], ["session,index,map,x_m,y_m,yaw_rad"]
    for g in gt:
        i = int(g["index"])
        dx = 0.5 if i >= 5 else 0.0
        x, y, yaw = float(g["x_m"]) + dx, float(g["y_m"]), float(g["yaw_rad"])
        odo.append(f"0,{i},{x},{y},{yaw}")
        traj.append(f"0,{i},0,{x},{y},{yaw}")
    last = int(gt[-1]["index"])
    (run / "odometry.csv").write_text("\n".join(odo) + "\n")
    (run / "trajectory.csv").write_text("\n".join(traj) + "\n")
    (run / "pieces.csv").write_text("session,piece,store_session,first_index,last_index,keyframes,map\n"
                                    f"0,0,0,0,4,5,0\n0,1,1,5,{last},{last - 4},0\n")
    loops = "session_a,index_a,session_b,index_b,kind,inliers\n"
    (run / "loops.csv").write_text(loops)
    g4, g5 = gt[4], gt[5]
    truth = bench_nav.evaluate.relative(*[(float(g["x_m"]), float(g["y_m"]), float(g["yaw_rad"])) for g in (g4, g5)])
    (run / "nav_placements.csv").write_text("session_a,index_a,session_b,index_b,x_m,y_m,yaw_rad,sigma_xy_m,"
                                            f"sigma_yaw_rad\n0,4,0,5,{truth[0] + 0.03},{truth[1]},{truth[2]},0.1,0.01\n")
    args = (str(run), [str(mission / "a")], str(mission / "world_gt.csv"))
    n, n_placed = len(gt), len(gt) - 5
    seen, _ = bench_nav.ate(*args, set())
    assert seen == pytest.approx(0.0, abs=2e-6)
    one_frame = bench_nav.one_frame_ate(*args, set())
    assert one_frame == pytest.approx(math.sqrt(n_placed * 0.25 / n), abs=2e-6)
    [(error, sigma)] = bench_nav.placement_errors(*args)
    assert error == pytest.approx(0.03, abs=2e-6) and sigma == 0.1
    (run / "loops.csv").write_text(loops + "0,2,0,7,global,80\n")
    assert bench_nav.ate(*args, set())[0] == pytest.approx(one_frame, abs=2e-6)
