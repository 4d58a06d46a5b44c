"""offline_slam's contract (offline_slam --help): command line, output files and their columns,
session numbering, and clear failures on bad input. Runs on a small generated survey."""
import math
import os
import re
import shutil
import sqlite3
import subprocess
import time
from pathlib import Path

import pytest
import yaml
from tool_runner import BIN_DIR, HERE, TWO_DIVES as SURVEY, make_survey, read_csv as rows, run_tool as run



@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    return make_survey(tmp_path_factory.mktemp("slam"), SURVEY)


@pytest.fixture(scope="module")
def result(survey, tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    r = run("offline_slam", "--session", str(survey / "a"), "--session", str(survey / "b"), "--out", str(out))
    assert r.returncode == 0, r.stderr
    return out, r


def test_writes_the_four_files_with_the_contract_columns(result):
    out, _ = result
    headers = {
        "odometry.csv": "session,index,x_m,y_m,yaw_rad",
        "trajectory.csv": "session,index,map,x_m,y_m,yaw_rad",
        "loops.csv": "session_a,index_a,session_b,index_b,kind,inliers",
        "timing.csv": "stage,calls,total_ms,mean_ms,max_ms",
    }
    for name, header in headers.items():
        with open(out / name) as f:
            assert f.readline().strip() == header, name
    stages = {r["stage"] for r in rows(out / "timing.csv")}
    assert {"features", "match", "ransac", "odometry_total"} <= stages


def test_sessions_numbered_by_position_and_indexes_from_frames_csv(result, survey):
    out, r = result
    odo = rows(out / "odometry.csv")
    assert {o["session"] for o in odo} == {"0", "1"}
    for s, name in [(0, "a"), (1, "b")]:
        frame_indexes = {f["index"] for f in rows(survey / name / "frames.csv")}
        mine = [o for o in odo if o["session"] == str(s)]
        assert mine[0]["index"] == "0" and float(mine[0]["x_m"]) == 0.0  # each session in its own frame
        assert {o["index"] for o in mine} <= frame_indexes
        assert 2 < len(mine) < len(frame_indexes)  # keyframes only
    assert "session 0" in r.stdout and "session 1" in r.stdout and "fallbacks" in r.stdout


def test_odometry_follows_the_ground_truth(result, survey):
    out, _ = result
    gt = {g["index"]: g for g in rows(survey / "a" / "gt.csv")}
    odo = [o for o in rows(out / "odometry.csv") if o["session"] == "0"]
    last = odo[-1]
    ref = gt[last["index"]]
    err = math.hypot(float(last["x_m"]) - float(ref["x_m"]), float(last["y_m"]) - float(ref["y_m"]))
    assert err < 0.05, err  # about 9 m of path on textured seabed


def test_trajectory_holds_the_same_keyframes_and_the_map_of_each_session(result):
    out, _ = result
    odo, traj = rows(out / "odometry.csv"), rows(out / "trajectory.csv")
    assert len(odo) == len(traj)
    for o, t in zip(odo, traj):
        assert (o["session"], o["index"]) == (t["session"], t["index"])
    first = traj[0]
    assert first["map"] == "0" and float(first["x_m"]) == 0.0 and float(first["y_m"]) == 0.0


def _in_frame(origin, p):
    """Pose p expressed in the frame of pose origin (both (x, y, yaw))."""
    c, s = math.cos(origin[2]), math.sin(origin[2])
    dx, dy = p[0] - origin[0], p[1] - origin[1]
    yaw = math.atan2(math.sin(p[2] - origin[2]), math.cos(p[2] - origin[2]))
    return (c * dx + s * dy, -s * dx + c * dy, yaw)


def test_sessions_are_joined_into_one_map_close_to_the_truth(result, survey):
    """The loop session b revisits a's ground: its global loops join it to map 0 through one link,
    and its poses in map 0's frame (session a's first keyframe) match the ground truth."""
    out, r = result
    links = rows(out / "links.csv")
    assert len(links) == 1 and links[0]["previous_session"] == "0" and links[0]["current_session"] == "1"
    assert int(links[0]["loops"]) >= 5  # join_min_loops
    assert "joined map 1 to map 0" in r.stdout
    errs = _joined_session_errors(out, survey)
    assert len(errs) > 3
    assert max(errs) < 0.05, errs  # a few cm on 2 x 1.6 m, ~3 m from session a's start


def _joined_session_errors(out, survey):
    """Session 1's position errors (m) in map 0's frame (session 0's first keyframe), everything in
    map 0."""
    traj = rows(out / "trajectory.csv")
    assert {t["map"] for t in traj} == {"0"}
    world = {(g["session"], g["index"]): (float(g["x_m"]), float(g["y_m"]), float(g["yaw_rad"]))
             for g in rows(survey / "world_gt.csv")}
    origin = world[("0", traj[0]["index"])]
    errs = []
    for t in traj:
        if t["session"] != "1":
            continue
        gt = _in_frame(origin, world[("1", t["index"])])
        errs.append(math.hypot(float(t["x_m"]) - gt[0], float(t["y_m"]) - gt[1]))
    return errs


def test_orb_features_join_the_sessions_and_a_store_keeps_to_their_kind(survey, tmp_path):
    """odometry.features.type orb: binary features, Hamming matching and their
    hashes join the survey's two sessions through global loops, every one of them true, close to
    the truth; a store of ORB keyframes serves the next ORB run and refuses a SIFT one with one
    line naming both kinds, the file left as it was."""
    cfg = tmp_path / "orb.yaml"
    cfg.write_text("odometry:\n  features:\n    type: orb\n")
    db = tmp_path / "maps.db"
    r1 = run("offline_slam", "--session", str(survey / "a"), "--out", str(tmp_path / "r1"), "--db", str(db),
             "--config", str(cfg))
    assert r1.returncode == 0, r1.stderr
    before = db.read_bytes()
    sift = run("offline_slam", "--session", str(survey / "b"), "--out", str(tmp_path / "sift"), "--db", str(db))
    assert sift.returncode != 0
    assert "orb features" in sift.stderr and "extracts sift" in sift.stderr, sift.stderr
    assert len(sift.stderr.strip().splitlines()) == 1, sift.stderr
    assert db.read_bytes() == before
    r2 = run("offline_slam", "--session", str(survey / "b"), "--out", str(tmp_path / "r2"), "--db", str(db),
             "--config", str(cfg))
    assert r2.returncode == 0, r2.stderr
    assert "joined map 1 to map 0" in r2.stdout
    errs = _joined_session_errors(tmp_path / "r2", survey)
    assert len(errs) > 3
    assert max(errs) < 0.05, errs  # SIFT's bound above
    glob = [l for l in rows(tmp_path / "r2" / "loops.csv") if l["kind"] == "global"]
    assert len(glob) >= 5  # join_min_loops
    # Every global loop is true: its measured pose of b in a's frame is the ground truth's within
    # 5 cm (a wrong loop is off by a footprint, metres).
    world = {(g["session"], g["index"]): (float(g["x_m"]), float(g["y_m"]), float(g["yaw_rad"]))
             for g in rows(survey / "world_gt.csv")}
    poses = rows(tmp_path / "r2" / "loop_poses.csv")
    measured = [p for p in poses if p["session_a"] != p["session_b"]]
    assert len(measured) == len(glob)
    for p in measured:
        gt = _in_frame(world[(p["session_a"], p["index_a"])], world[(p["session_b"], p["index_b"])])
        assert math.hypot(float(p["x_m"]) - gt[0], float(p["y_m"]) - gt[1]) < 0.05, (p, gt)


def test_no_join_when_the_configuration_forbids_it(survey, tmp_path):
    cfg = tmp_path / "nojoin.yaml"
    cfg.write_text("backend:\n  join_min_loops: 0\n")
    out = tmp_path / "o"
    r = run("offline_slam", "--session", str(survey / "a"), "--session", str(survey / "b"), "--out", str(out),
            "--config", str(cfg))
    assert r.returncode == 0, r.stderr
    # The run records the configuration it ran with: the changed value, and it reads back the same.
    recorded = (out / "config.yaml").read_text()
    assert yaml.safe_load(recorded)["backend"]["join_min_loops"] == 0
    dumped = run("offline_slam", "--config", str(cfg), "--dump-config").stdout
    assert run("offline_slam", "--config", str(out / "config.yaml"), "--dump-config").stdout == dumped
    traj = rows(out / "trajectory.csv")
    for t in traj:
        assert t["map"] == t["session"]  # each session its own map, in its own frame
    firsts = [t for t in traj if t["session"] == "1"][:1]
    assert firsts and float(firsts[0]["x_m"]) == 0.0 and float(firsts[0]["y_m"]) == 0.0
    assert rows(out / "links.csv") == []


ALTIMETER_NOISE_M = 0.01  # make_survey's altimeter_noise_m (SURVEY leaves the default)
ALTITUDE_A_M = 2.0        # session a's altitude in SURVEY


def test_the_back_end_brings_the_revisits_closer_to_the_truth(result, survey):
    """Session a goes out and back: with its loops, the optimised trajectory's relative poses
    between revisited keyframes (the paper's e_k) are as close to the truth as the loops' noise
    allows, which the odometry's are not.

    The bound from the noise: a loop's translation is scaled by keyframe a's altitude reading, off
    by N(0, noise / altitude) relatively, so it errs along itself by sigma_k = |X_b^a| x noise /
    altitude (the registration adds well under a millimetre: its covariance in loop_poses.csv).
    The optimised relative pose follows the loop, far tighter than the chain between a and b, so
    |e_k| is half-normal: mean sigma_k sqrt(2 / pi), variance sigma_k^2 (1 - 2 / pi). Their mean
    over the N loops must stay within 3 standard deviations of its expectation."""
    out, r = result
    assert "optimisations" in r.stdout
    gt = {g["index"]: (float(g["x_m"]), float(g["y_m"]), float(g["yaw_rad"])) for g in rows(survey / "a" / "gt.csv")}

    def poses(name):
        return {o["index"]: (float(o["x_m"]), float(o["y_m"]), float(o["yaw_rad"]))
                for o in rows(out / name) if o["session"] == "0"}

    def rel(p, q):  # position of q in p's frame
        c, s = math.cos(p[2]), math.sin(p[2])
        dx, dy = q[0] - p[0], q[1] - p[1]
        return (c * dx + s * dy, -s * dx + c * dy)

    loops = [(l["index_a"], l["index_b"]) for l in rows(out / "loops.csv")
             if l["session_a"] == "0" and l["session_b"] == "0"]
    assert loops
    def e_k(est):
        errs = []
        for a, b in loops:
            ea, eg = rel(est[a], est[b]), rel(gt[a], gt[b])
            errs.append(math.hypot(ea[0] - eg[0], ea[1] - eg[1]))
        return sum(errs) / len(errs)
    sigmas = []
    for a, b in loops:
        dx, dy = rel(gt[a], gt[b])
        sigmas.append(math.hypot(dx, dy) * ALTIMETER_NOISE_M / ALTITUDE_A_M)
    n = len(sigmas)
    bound = (math.sqrt(2 / math.pi) * sum(sigmas) / n
             + 3 * math.sqrt(sum(x * x for x in sigmas) * (1 - 2 / math.pi)) / n)
    optimised, odometry = e_k(poses("trajectory.csv")), e_k(poses("odometry.csv"))
    assert optimised < bound, (optimised, bound)
    assert odometry > bound, (odometry, bound)  # the odometry alone would not pass


def test_bad_input_fails_with_one_line(tmp_path, survey):
    r = run("offline_slam", "--session", str(tmp_path / "nope"), "--out", str(tmp_path / "o"))
    assert r.returncode == 1 and "not a directory" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "camera.yaml").write_text((survey / "a" / "camera.yaml").read_text())
    (broken / "frames.csv").write_text("index,image,stamp_s,altitude_m\n0,0000.jpg,0.0,two\n")
    r = run("offline_slam", "--session", str(survey / "a"), "--session", str(broken), "--out", str(tmp_path / "o"))
    assert r.returncode == 1 and "frames.csv:2: bad number in altitude_m" in r.stderr
    assert not (tmp_path / "o" / "odometry.csv").exists()  # folders are checked before any work
    assert run("offline_slam", "--out", str(tmp_path / "o")).returncode == 2
    assert run("offline_slam", "--bogus").returncode == 2
    cfg = tmp_path / "c.yaml"
    cfg.write_text("odometry:\n  ransac: {inlier_treshold_px: 3}\n")
    r = run("offline_slam", "--config", str(cfg), "--session", str(survey / "a"), "--out", str(tmp_path / "o"))
    assert r.returncode == 1 and "unknown key 'inlier_treshold_px'" in r.stderr


def test_unreadable_image_is_skipped_and_counted(tmp_path, survey):
    folder = tmp_path / "a"
    os.system(f"cp -r {survey / 'a'} {folder}")
    (folder / "0003.jpg").write_bytes(b"not a jpeg")
    r = run("offline_slam", "--session", str(folder), "--out", str(tmp_path / "o"))
    assert r.returncode == 0, r.stderr
    assert "0003.jpg" in r.stderr and "skipped" in r.stderr
    assert "1 skipped (1 image" in r.stdout


def test_a_camera_of_another_size_than_the_images_is_refused_before_the_run(tmp_path, survey):
    """camera.yaml of 640 px for 320 px images: every frame would be skipped (the run used to exit 0
    with "no session started"). Refused with exit 1 in one line naming both sizes, nothing written."""
    folder = tmp_path / "a"
    shutil.copytree(survey / "a", folder)
    camera = yaml.safe_load((folder / "camera.yaml").read_text())
    doubled = {k: 2 * v for k, v in camera.items()}
    (folder / "camera.yaml").write_text("".join("%s: %s\n" % kv for kv in doubled.items()))
    r = run("offline_slam", "--session", survey / "b", "--session", folder, "--out", tmp_path / "o")
    assert r.returncode == 1, r.stdout
    assert r.stderr.strip().splitlines() == [
        "offline_slam: %s/camera.yaml: a camera of %dx%d px, but the images are %dx%d px ('0000.jpg', frame 0): every "
        "frame would be skipped; give the camera of these images (a calibration made at another resolution scales "
        "image_width, image_height, fx, fy, cx and cy by the same factor)" % (
            folder, doubled["image_width"], doubled["image_height"], camera["image_width"], camera["image_height"])]
    assert not (tmp_path / "o").exists()  # checked before any work or output


def test_the_session_line_is_whole_for_a_long_folder_path(tmp_path, survey):
    """The session's summary line names its folder: a long path (250 characters, near the 256 a
    session name may have) must not cut the counts after it (a 400-byte buffer did)."""
    folder = tmp_path / ("d" * (250 - len(str(tmp_path)) - 3)) / "a"
    assert len(str(folder)) == 250
    shutil.copytree(survey / "a", folder)
    r = run("offline_slam", "--session", str(folder), "--out", str(tmp_path / "o"))
    assert r.returncode == 0, r.stderr
    (line,) = [x for x in r.stdout.splitlines() if x.startswith("session 0 (%s): " % folder)]
    assert re.search(r"\d+ altitudes reused \(0 above odometry\.max_altitude_m\), \d+\.\d ms/frame$", line), line


def test_dump_config_round_trips(tmp_path):
    dumped = run("offline_slam", "--dump-config").stdout
    spec = yaml.safe_load(dumped)
    assert spec["odometry"]["features"]["num_features"] == 500
    (tmp_path / "c.yaml").write_text(dumped)
    assert run("offline_slam", "--config", str(tmp_path / "c.yaml"), "--dump-config").stdout == dumped


def test_config_slam_yaml_documents_the_defaults():
    path = os.path.join(HERE, "..", "..", "config", "slam.yaml")
    documented = run("offline_slam", "--config", path, "--dump-config")
    assert documented.returncode == 0, documented.stderr
    assert documented.stdout == run("offline_slam", "--dump-config").stdout


def test_loops_reference_keyframes_and_have_measured_poses(result, survey):
    out, r = result
    loops = rows(out / "loops.csv")
    poses = rows(out / "loop_poses.csv")
    assert len(loops) == len(poses)
    keyframes = {(o["session"], o["index"]) for o in rows(out / "odometry.csv")}
    kinds = set()
    for loop, pose in zip(loops, poses):
        assert (loop["session_a"], loop["index_a"]) in keyframes and (loop["session_b"], loop["index_b"]) in keyframes
        assert loop["kind"] == ("local" if loop["session_a"] == loop["session_b"] else "global")
        assert int(loop["inliers"]) >= 20  # loops.local/global.min_inliers
        assert (pose["session_a"], pose["index_a"], pose["session_b"], pose["index_b"]) == (
            loop["session_a"], loop["index_a"], loop["session_b"], loop["index_b"])
        kinds.add(loop["kind"])
    # Session a goes out and back 1 m apart (a revisit); session b crosses a's area.
    assert kinds == {"local", "global"}, loops
    assert "loops:" in r.stdout


def test_an_unwritable_output_file_is_an_error(tmp_path, survey):
    out = tmp_path / "o"
    (out / "loops.csv").mkdir(parents=True)  # a directory where the file must go
    r = run("offline_slam", "--session", str(survey / "a"), "--out", str(out))
    assert r.returncode == 1 and "cannot write" in r.stderr


# --- --db FILE: the session store -------------------------------------------------------------

@pytest.fixture(scope="module")
def stored_runs(survey, tmp_path_factory):
    """Session a processed with --db, then session b with the same --db (tomorrow's mission)."""
    base = tmp_path_factory.mktemp("db")
    db = base / "maps.db"
    r1 = run("offline_slam", "--session", str(survey / "a"), "--out", str(base / "r1"), "--db", str(db))
    assert r1.returncode == 0, r1.stderr
    r2 = run("offline_slam", "--session", str(survey / "b"), "--out", str(base / "r2"), "--db", str(db))
    assert r2.returncode == 0, r2.stderr
    return base, r1, r2


def test_db_stored_sessions_come_first_and_are_joined_like_one_run(stored_runs, result):
    base, r1, r2 = stored_runs
    out = base / "r2"
    traj = rows(out / "trajectory.csv")
    assert {t["session"] for t in traj} == {"0", "1"}  # 0 from the store, 1 from the command line
    assert {o["session"] for o in rows(out / "odometry.csv")} == {"0", "1"}
    stored = [(t["session"], t["index"]) for t in rows(base / "r1" / "trajectory.csv")]
    assert [(t["session"], t["index"]) for t in traj if t["session"] == "0"] == stored
    assert "1 sessions" in r2.stdout and "joined map 1 to map 0" in r2.stdout
    assert {t["map"] for t in traj} == {"0"}  # b joined to the stored session's map
    loops = rows(out / "loops.csv")
    glob = [l for l in loops if l["kind"] == "global"]
    assert len(glob) >= 5 and all(l["session_a"] == "0" and l["session_b"] == "1" for l in glob)
    # The stored session's local loops are reported again, like the others.
    assert {tuple(l.values()) for l in rows(base / "r1" / "loops.csv")} <= {tuple(l.values()) for l in loops}
    # The same as processing both folders in one run: same loops, same trajectories.
    one_run, _ = result
    key = lambda l: tuple(l.values())
    assert sorted(map(key, loops)) == sorted(map(key, rows(one_run / "loops.csv")))
    for a, b in zip(traj, rows(one_run / "trajectory.csv")):
        assert (a["session"], a["index"], a["map"]) == (b["session"], b["index"], b["map"])
        assert abs(float(a["x_m"]) - float(b["x_m"])) < 1e-5 and abs(float(a["y_m"]) - float(b["y_m"])) < 1e-5
    assert rows(out / "links.csv") == rows(one_run / "links.csv")


def test_db_keeps_the_joined_map_for_the_next_run(stored_runs, survey, tmp_path):
    """A third run finds both stored sessions in one map and appends session 2."""
    base, _, r2 = stored_runs
    db = tmp_path / "copy.db"
    db.write_bytes((base / "maps.db").read_bytes())
    r = run("offline_slam", "--session", str(survey / "a"), "--out", str(tmp_path / "o"), "--db", str(db), "--again")
    assert r.returncode == 0, r.stderr
    traj = rows(tmp_path / "o" / "trajectory.csv")
    assert {t["session"] for t in traj} == {"0", "1", "2"}
    before = {(t["session"], t["index"]): t for t in rows(base / "r2" / "trajectory.csv")}
    for t in traj:
        if t["session"] == "1":
            assert t["map"] == "0"  # still joined
    # a second time over the same ground: globally looped to the stored sessions and joined
    assert {t["map"] for t in traj if t["session"] == "2"} == {"0"}
    assert len(before) == len([t for t in traj if t["session"] in ("0", "1")])


def test_db_refuses_a_folder_already_in_the_store_unless_again(stored_runs, survey, tmp_path):
    """Folder a is session 0 of the store: running it again is refused, naming the folder and the
    stored session, and the store is left as it is; so is b."""
    base, _, _ = stored_runs
    db = tmp_path / "copy.db"
    db.write_bytes((base / "maps.db").read_bytes())
    before = db.read_bytes()
    for folder, session in (("a", 0), ("b", 1)):
        r = run("offline_slam", "--session", str(survey / folder), "--out", str(tmp_path / folder), "--db", str(db))
        assert r.returncode == 3, r.stderr  # its own status: 2 is for bad arguments
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and str(survey / folder) in lines[0] and "(session %d)" % session in lines[0], lines
        assert "--again" in lines[0]
        assert not (tmp_path / folder).exists()  # refused before any output
    assert db.read_bytes() == before


def store_rows(db, sql):
    con = sqlite3.connect("file:%s?mode=ro" % db, uri=True, timeout=5)
    try:
        return con.execute(sql).fetchall()
    finally:
        con.close()


def keyframes_in(db):
    try:
        return store_rows(db, "SELECT count(*) FROM keyframes")[0][0]
    except sqlite3.Error:
        return 0  # not created yet, or locked for a moment


@pytest.fixture
def interrupted(survey, tmp_path):
    """offline_slam --db over folders a and b, killed -9 once 5 keyframes are stored: folder a's
    session is left `recording`. Returns the store and the command's arguments."""
    db = tmp_path / "s.db"
    args = ["--session", str(survey / "a"), "--session", str(survey / "b"), "--out", str(tmp_path / "o1"),
            "--db", str(db)]
    proc = subprocess.Popen([os.path.join(BIN_DIR, "offline_slam"), "--quiet", *args], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while keyframes_in(db) < 5 and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.02)
        assert proc.poll() is None, "the run ended before it could be killed"
        assert keyframes_in(db) >= 5
    finally:
        proc.kill()
        proc.wait()
    assert store_rows(db, "SELECT name, state FROM sessions") == [(str(survey / "a"), "recording")]
    return db, args


def test_db_rerun_after_kill_is_refused_naming_the_interrupted_option(interrupted, survey):
    """The re-run of the killed command is refused with its own status (3, not the
    bad-arguments 2), in one line naming the folder and both choices; the store is left as it is."""
    db, args = interrupted
    before = store_rows(db, "SELECT session, keyframe, frame_index, stamp FROM keyframes ORDER BY session, keyframe")
    r = run("offline_slam", "--quiet", *args)
    assert r.returncode == 3, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and str(survey / "a") in lines[0], lines
    assert "--interrupted discard" in lines[0] and "--interrupted finish" in lines[0], lines
    assert store_rows(db, "SELECT session, keyframe, frame_index, stamp FROM keyframes ORDER BY session, keyframe") == before
    assert store_rows(db, "SELECT name, state FROM sessions") == [(str(survey / "a"), "recording")]
    assert "--interrupted discard|finish" in run("offline_slam", "--help").stdout
    bad = run("offline_slam", "--quiet", *args, "--interrupted", "keep")
    assert bad.returncode == 2 and "discard or finish" in bad.stderr


def test_db_rerun_after_kill_with_discard_processes_the_folder_again_as_one_clean_run(interrupted, survey, result):
    """--interrupted discard deletes the interrupted session (its keyframes, motions, loops) and
    processes both folders again: the store holds each folder once, and the outputs are those of
    a run that was never interrupted (same keyframes, loops and links; poses to 1e-5 m)."""
    db, args = interrupted
    out = args[args.index("--out") + 1]
    r = run("offline_slam", "--quiet", *args, "--interrupted", "discard")
    assert r.returncode == 0, r.stderr
    assert "deleted" in r.stderr and str(survey / "a") in r.stderr
    assert store_rows(db, "SELECT name, state FROM sessions ORDER BY id") == [
        (str(survey / "a"), "finished"), (str(survey / "b"), "finished")]
    assert store_rows(db, "PRAGMA integrity_check") == [("ok",)]
    # The audit trail: the deletion by the tool, then the rule's join of the new run.
    history = store_rows(db, "SELECT id, kind, cause, sessions, message FROM history ORDER BY id")
    assert history[0][:4] == (1, "delete", "tool", "0") and str(survey / "a") in history[0][4], history
    # A session's id is its store id for life and is never given twice: the deleted session 0's id
    # stays unused, so the new run's sessions are 1 and 2, in the store, its history and the CSV
    # files (folders numbered from the first new id), where a clean run has 0 and 1.
    assert [h[1:4] for h in history[1:]] == [("join", "automatic", "1+2")], history
    assert store_rows(db, "SELECT id FROM sessions ORDER BY id") == [(1,), (2,)]
    one_run, _ = result
    shift = {"session", "session_a", "session_b", "map", "previous_session", "current_session"}
    key = lambda l: tuple(str(int(v) - 1) if k in shift else v for k, v in l.items())
    assert sorted(map(key, rows(os.path.join(out, "loops.csv")))) == sorted(map(tuple, (l.values() for l in rows(
        one_run / "loops.csv"))))
    assert list(map(key, rows(os.path.join(out, "links.csv")))) == list(map(tuple, (l.values() for l in rows(
        one_run / "links.csv"))))
    traj, clean = rows(os.path.join(out, "trajectory.csv")), rows(one_run / "trajectory.csv")
    assert len(traj) == len(clean)
    for a, b in zip(traj, clean):
        assert (int(a["session"]) - 1, a["index"], int(a["map"]) - 1) == (int(b["session"]), b["index"], int(b["map"]))
        assert abs(float(a["x_m"]) - float(b["x_m"])) < 1e-5 and abs(float(a["y_m"]) - float(b["y_m"])) < 1e-5
    # Each stored keyframe once: as many as the run's trajectory has.
    assert keyframes_in(db) == len(traj)
    # A third run of the same command: folder a is in the store, finished: --again is named.
    again = run("offline_slam", "--quiet", *args)
    assert again.returncode == 3 and "--again" in again.stderr


def test_db_rerun_after_kill_with_finish_keeps_the_stored_part_and_skips_the_folder(interrupted, survey):
    """--interrupted finish keeps the keyframes stored before the kill, marks the session
    finished, skips folder a and processes b (stored session 0, then b as session 1)."""
    db, args = interrupted
    kept = store_rows(db, "SELECT session, keyframe, frame_index, stamp, hash FROM keyframes ORDER BY session, keyframe")
    r = run("offline_slam", "--quiet", *args, "--interrupted", "finish")
    assert r.returncode == 0, r.stderr
    assert "marked finished" in r.stderr and "skipped" in r.stderr
    assert store_rows(db, "SELECT name, state FROM sessions ORDER BY id") == [
        (str(survey / "a"), "finished"), (str(survey / "b"), "finished")]
    first = kept[0][0]
    assert store_rows(db, "SELECT session, keyframe, frame_index, stamp, hash FROM keyframes WHERE session = %d "
                          "ORDER BY keyframe" % first) == kept
    assert store_rows(db, "PRAGMA integrity_check") == [("ok",)]
    out = args[args.index("--out") + 1]
    traj = rows(os.path.join(out, "trajectory.csv"))
    assert len([t for t in traj if t["session"] == "0"]) == len(kept)
    assert {t["session"] for t in traj} == {"0", "1"}
    assert [i["folder"] for i in rows(os.path.join(out, "inputs.csv"))] == [str(survey / "b")]


def test_db_bad_file_fails_with_one_line_and_is_left_as_it_is(tmp_path, survey):
    bad = tmp_path / "notes.db"
    bad.write_text("these are notes, not a session store\n" * 10)
    before = bad.read_bytes()
    r = run("offline_slam", "--session", str(survey / "a"), "--out", str(tmp_path / "o"), "--db", str(bad))
    assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1
    assert str(bad) in r.stderr and "not an SQLite database" in r.stderr
    assert bad.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.db"]  # nothing written beside it, no output


LOST = """
seed: 3
world: {width_m: 12, height_m: 10, featureless_fraction: 0}
sessions:
  - name: a
    mission: {pattern: loop, start_m: [3.5, 2.5], length_m: 4.0, width_m: 3.0, laps: 2.1,
              speed_m_s: 0.4, frame_period_s: 1.0, altitude_m: 2.0}
    water:
      stretches:
        - {first_frame: 10, num_frames: 7, kind: blank}
"""


def test_tracking_loss_starts_a_session_that_global_loops_join_back(tmp_path):
    """Seven blank frames in the first of two laps: tracking is lost, the session is closed and a
    new one starts when the seabed is back; the second lap's global loops join the pieces, and
    the joined map is within a few cm of the ground truth."""
    make_survey(tmp_path, LOST)
    out = tmp_path / "o"
    r = run("offline_slam", "--session", str(tmp_path / "m" / "a"), "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert "tracking lost at frame" in r.stdout and "tracking resumed at frame" in r.stdout
    traj = rows(out / "trajectory.csv")
    assert {t["session"] for t in traj} == {"0"}  # the folder's number for both pieces
    assert {t["map"] for t in traj} == {"0"}      # joined again
    links = rows(out / "links.csv")
    assert len(links) == 1 and links[0]["previous_session"] == "0" and links[0]["current_session"] == "0"
    assert (links[0]["previous_piece"], links[0]["current_piece"]) == ("0", "1")
    # pieces.csv: the folder's two pieces, their own store sessions, split around the blank frames.
    pieces = rows(out / "pieces.csv")
    assert [(p["session"], p["piece"]) for p in pieces] == [("0", "0"), ("0", "1")]
    assert pieces[0]["store_session"] != pieces[1]["store_session"]
    assert int(pieces[0]["last_index"]) < 10 and int(pieces[1]["first_index"]) >= 17
    assert sum(int(p["keyframes"]) for p in pieces) == len(traj) == len(rows(out / "odometry.csv"))
    assert {p["map"] for p in pieces} == {"0"}
    # evaluate.py scores each piece in its own row ("0.0", "0.1"), its odometry in its own frame.
    report = tmp_path / "report"
    r = subprocess.run(["/usr/bin/python3", os.path.join(HERE, "..", "..", "src", "tools", "evaluate.py"), "--run",
                        str(out), "--session", str(tmp_path / "m" / "a"), "--report", str(report), "--no-plots"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    scored = yaml.safe_load((report / "metrics.json").read_text())["session"]
    assert sorted(scored) == ["0.0", "0.1"]
    for name, piece in zip(("0.0", "0.1"), pieces):
        assert scored[name]["odometry"]["n_keyframes"] == int(piece["keyframes"])
        assert scored[name]["odometry"]["ate_rmse_m"] < 0.05, (name, scored[name]["odometry"])
    indexes = [int(t["index"]) for t in traj]
    assert len(indexes) == len(set(indexes))  # unique within the folder
    assert not any(10 <= i < 17 for i in indexes)  # no keyframe in the blank stretch
    gt = {int(g["index"]): (float(g["x_m"]), float(g["y_m"])) for g in rows(tmp_path / "m" / "a" / "gt.csv")}
    worst = max(math.hypot(float(t["x_m"]) - gt[int(t["index"])][0], float(t["y_m"]) - gt[int(t["index"])][1])
                for t in traj)
    assert worst < 0.05, worst
    # Without the split (max_fallbacks 0) the same run keeps one session with reused motions.
    cfg = tmp_path / "never.yaml"
    cfg.write_text("tracking:\n  max_fallbacks: 0\n")
    r = run("offline_slam", "--session", str(tmp_path / "m" / "a"), "--out", str(tmp_path / "o2"), "--config", str(cfg))
    assert r.returncode == 0 and "tracking lost" not in r.stdout
    assert rows(tmp_path / "o2" / "links.csv") == []


@pytest.fixture(scope="module")
def short_revisits(tmp_path_factory):
    """config/missions/short_revisits.yaml: five 4-5 frame passes over one patch, a sixth elsewhere."""
    base = tmp_path_factory.mktemp("short")
    mission = Path(HERE, "..", "..", "config", "missions", "short_revisits.yaml")
    make_survey(base, mission)
    runs = {}
    for policy in ("count", "consistent"):
        (base / (policy + ".yaml")).write_text("backend:\n  join_policy: %s\n" % policy)
        out = base / policy
        r = run("offline_slam", *[a for s in range(6) for a in ("--session", str(base / "m" / ("p%d" % s)))],
                "--out", str(out), "--config", str(base / (policy + ".yaml")))
        assert r.returncode == 0, r.stderr
        runs[policy] = out
    return base / "m", runs


def test_consistency_joins_every_short_revisit_and_nothing_else(short_revisits):
    """The five passes over one patch share 2-4 correct loops per pair, never K = 5: the
    count policy leaves six maps, the consistent one joins the five passes into one map (in its
    first pass's frame, within 3 cm of the truth) and leaves the pass over other ground alone."""
    mission, runs = short_revisits
    assert rows(runs["count"] / "links.csv") == []
    traj = rows(runs["consistent"] / "trajectory.csv")
    maps = {}
    for t in traj:
        maps.setdefault(t["map"], set()).add(int(t["session"]))
    assert sorted(maps.values(), key=min) == [{0, 1, 2, 3, 4}, {5}]
    world = {(g["session"], g["index"]): (float(g["x_m"]), float(g["y_m"]), float(g["yaw_rad"]))
             for g in rows(mission / "world_gt.csv")}
    origin = world[("0", traj[0]["index"])]
    errs = [math.hypot(float(t["x_m"]) - gt[0], float(t["y_m"]) - gt[1])
            for t in traj if t["session"] != "5" for gt in [_in_frame(origin, world[(t["session"], t["index"])])]]
    assert len(errs) >= 10
    assert max(errs) < 0.03, errs  # measured 6 mm ATE; a wrong link puts a pass ~1 m off


EVALUATE = os.path.join(HERE, "..", "..", "src", "tools", "evaluate.py")


def test_inputs_csv_lets_evaluate_refuse_another_folder(result, survey, tmp_path):
    out, _ = result
    inputs = rows(out / "inputs.csv")
    assert [(i["session"], i["folder"]) for i in inputs] == [("0", str(survey / "a")), ("1", str(survey / "b"))]
    frames = rows(survey / "a" / "frames.csv")
    assert int(inputs[0]["frames"]) == len(frames)
    assert float(inputs[0]["last_stamp_s"]) == pytest.approx(float(frames[-1]["stamp_s"]), abs=1e-6)

    def evaluate(*folders):
        args = ["/usr/bin/python3", EVALUATE, "--run", str(out), "--report", str(tmp_path / "report"), "--no-plots"]
        for folder in folders:
            args += ["--session", str(folder)]
        return subprocess.run(args, capture_output=True, text=True, timeout=120)

    assert evaluate(survey / "a", survey / "b").returncode == 0
    # A copy of folder a with other altitudes (same indexes and stamps, like ACFR test1 and test2).
    shutil.copytree(survey / "a", tmp_path / "a2")
    with open(tmp_path / "a2" / "frames.csv", "w") as f:
        f.write("index,image,stamp_s,altitude_m\n")
        f.writelines("%s,%s,%s,%.4f\n" % (r["index"], r["image"], r["stamp_s"], float(r["altitude_m"]) + 0.05)
                     for r in frames)
    refused = evaluate(tmp_path / "a2", survey / "b")
    assert refused.returncode == 1
    assert "session 0 of the run was made from %s" % (survey / "a") in refused.stderr
    assert "not the same folder" in refused.stderr


def test_db_inputs_csv_numbers_the_folders_after_the_stored_sessions(stored_runs, survey):
    base, _, _ = stored_runs
    assert [(i["session"], i["folder"]) for i in rows(base / "r2" / "inputs.csv")] == [("1", str(survey / "b"))]


def test_db_prints_which_folder_got_which_session_ids_once(stored_runs, survey):
    """The mapping from the command line to session ids (the store's, the services', export_survey's),
    printed once per run: folder b, the first folder after stored session 0, is CSV session 1 and
    store session 1."""
    _, r1, r2 = stored_runs
    for r, number, folder in ((r1, 0, survey / "a"), (r2, 1, survey / "b")):
        assert r.stdout.count("session ids (CSV session -> store session ids):") == 1, r.stdout
        assert "\n  %d %s -> %d '%s'\n" % (number, folder, number, folder) in r.stdout, r.stdout


def unrelated_folder(path):
    """A dataset folder of ../shared/data/posidonia_queries: 75 real seagrass and rock frames from
    another sea (480x270, not a sequence), with a plausible camera and altitude."""
    source = os.path.join(HERE, "..", "..", "..", "shared", "data", "posidonia_queries")
    names = sorted(n for n in os.listdir(source) if n.endswith(".jpg"))
    os.makedirs(path)
    for n in names:
        shutil.copy(os.path.join(source, n), path / n)
    (path / "frames.csv").write_text("index,image,stamp_s,altitude_m\n" + "".join(
        "%d,%s,%.1f,2.0\n" % (i, n, 1000.0 + i) for i, n in enumerate(names)))
    (path / "camera.yaml").write_text("image_width: 480\nimage_height: 270\nfx: 400\nfy: 400\ncx: 239.5\ncy: 134.5\n")
    return path


def test_an_unrelated_session_between_two_of_one_mission_gets_no_loop_and_no_join(survey, tmp_path):
    """Real frames of another sea between the two sessions of one mission: no loop
    touches them and they join nothing, while the mission's two sessions still join. Without the
    odometry's dense pass, which registers consecutive frames of one stream only and is most of
    this run's cost on frames that do not follow each other: the unrelated frames still give over
    20 keyframes, each queried against the mission's (global loops and joins do not use it)."""
    unrelated = unrelated_folder(tmp_path / "posidonia")
    out = tmp_path / "o"
    cfg = tmp_path / "no_dense.yaml"
    cfg.write_text("odometry:\n  dense:\n    enabled: false\n")
    r = run("offline_slam", "--session", str(survey / "a"), "--session", str(unrelated), "--session", str(survey / "b"),
            "--out", str(out), "--config", str(cfg))
    assert r.returncode == 0, r.stderr
    # (Loops among the unrelated frames themselves may be right: some of them show the same marker.)
    across = [loop for loop in rows(out / "loops.csv") if "1" in (loop["session_a"], loop["session_b"]) and
              {loop["session_a"], loop["session_b"]} != {"1"}]
    assert not across
    traj = rows(out / "trajectory.csv")
    maps_of = {}
    for t in traj:
        maps_of.setdefault(t["session"], set()).add(t["map"])
    assert maps_of["0"] == maps_of["2"] and len(maps_of["0"]) == 1  # a and b joined again
    assert sum(t["session"] == "1" for t in traj) >= 20  # over 20 unrelated keyframes tried against the mission
    for m in maps_of.get("1", set()):  # whatever of the unrelated frames became keyframes, alone
        assert {t["session"] for t in traj if t["map"] == m} == {"1"}
    assert not [link for link in rows(out / "links.csv") if "1" in (link["previous_session"], link["current_session"])
                and {link["previous_session"], link["current_session"]} != {"1"}]


def test_finish_after_ends_each_folder_session_like_a_folder_cut_there(survey, tmp_path):
    """--finish-after N (finish_session offline): each folder's session ends after
    its first N frames; the rest are dropped and counted. The run equals one over copies of the
    folders whose frames.csv stops at N (same keyframes, same poses), its sessions are finished in
    the store, and the next folder is the next session. Bad values exit 2."""
    n = 12
    cut = {}
    for name in ("a", "b"):
        cut[name] = tmp_path / ("cut_" + name)
        shutil.copytree(survey / name, cut[name])
        lines = (survey / name / "frames.csv").read_text().splitlines()
        assert len(lines) > n + 1
        (cut[name] / "frames.csv").write_text("\n".join(lines[:n + 1]) + "\n")
    r = run("offline_slam", "--session", survey / "a", "--session", survey / "b", "--finish-after", n,
            "--db", tmp_path / "f.db", "--out", tmp_path / "f")
    assert r.returncode == 0, r.stdout + r.stderr
    for name in ("a", "b"):
        dropped = len((survey / name / "frames.csv").read_text().splitlines()) - 1 - n
        assert f"{survey / name}: session finished after {n} frames (--finish-after), {dropped} frames dropped" \
            in r.stdout, r.stdout
    r = run("offline_slam", "--session", cut["a"], "--session", cut["b"], "--out", tmp_path / "c", "--quiet")
    assert r.returncode == 0, r.stderr
    finished, whole = rows(tmp_path / "f" / "odometry.csv"), rows(tmp_path / "c" / "odometry.csv")
    assert [(t["session"], t["index"]) for t in finished] == [(t["session"], t["index"]) for t in whole]
    assert {t["session"] for t in finished} == {"0", "1"}
    assert max(int(t["index"]) for t in finished) < n
    for p, q in zip(finished, whole):
        assert all(abs(float(p[k]) - float(q[k])) < 1e-9 for k in ("x_m", "y_m", "yaw_rad")), (p, q)
    assert store_rows(tmp_path / "f.db", "SELECT state FROM sessions ORDER BY id") == [("finished",), ("finished",)]
    for bad in ("0", "-3", "x", "2.5"):
        r = run("offline_slam", "--session", survey / "a", "--finish-after", bad, "--out", tmp_path / "bad")
        assert r.returncode == 2 and "--finish-after" in r.stderr, (bad, r.stderr)
    assert not (tmp_path / "bad").exists()


@pytest.mark.parametrize("klt,features", [(False, "sift"), (True, "sift"), (False, "orb")])
def test_threads_give_the_same_outputs_as_one_thread(survey, tmp_path, klt, features):
    """--threads N: workers read and prepare the next frames while the main
    thread runs the rest; every output file is the same as with one thread, byte for byte (timing
    aside), with a corrupt and a cut-off image among the frames (both skipped, counted), with KLT on
    or off and with ORB features."""
    folder = tmp_path / "a"
    shutil.copytree(survey / "a", folder)
    (folder / "0004.jpg").write_bytes(b"not a jpeg")
    whole = (folder / "0007.jpg").read_bytes()
    (folder / "0007.jpg").write_bytes(whole[:len(whole) // 2])  # cut off: cv::imread alone decoded it half grey
    cfg = tmp_path / "c.yaml"
    cfg.write_text("odometry:\n  klt:\n    enabled: %s\n  features:\n    type: %s\n"
                   % ("true" if klt else "false", features))
    outs = {}
    for threads in (1, 2, 3):
        out = tmp_path / ("t%d" % threads)
        r = run("offline_slam", "--session", str(folder), "--session", str(survey / "b"), "--out", str(out),
                "--config", str(cfg), "--threads", str(threads))
        assert r.returncode == 0, r.stderr
        assert "0004.jpg: cannot decode image" in r.stderr
        assert "0007.jpg: corrupt image (truncated JPEG: no end-of-image marker): frame 7 skipped" in r.stderr
        assert "2 skipped (2 image, 0 altitude)" in r.stdout
        assert "--threads %d)" % threads in r.stdout  # the throughput line
        outs[threads] = out
    files = sorted(p.name for p in outs[1].iterdir() if p.name != "timing.csv")
    assert {"trajectory.csv", "odometry.csv", "loops.csv", "links.csv"} <= set(files)
    assert len(rows(outs[1] / "links.csv")) == 1  # the two sessions joined: the loops ran too
    for threads in (2, 3):
        for name in files:
            assert (outs[threads] / name).read_bytes() == (outs[1] / name).read_bytes(), (threads, name)


def test_a_folder_with_no_usable_frame_says_so_once(survey, tmp_path):
    """Every image unreadable: each frame is a counted skip with its reason, and the folder ends
    with one line saying no session started and why (not silence where the session lines would
    be); the other folder is mapped as usual."""
    folder = tmp_path / "a"
    shutil.copytree(survey / "a", folder)
    images = sorted(folder.glob("*.jpg"))
    for image in images:
        image.write_bytes(b"not a jpeg")
    r = run("offline_slam", "--session", folder, "--session", survey / "b", "--out", tmp_path / "o")
    assert r.returncode == 0, r.stderr
    assert r.stderr.count("cannot decode image") == len(images)
    line = "stream %s: no session started: %d frames, %d of them without an image (unreadable)" % (
        folder, len(images), len(images))
    assert line in r.stdout, r.stdout
    assert "stream %s: no session started" % (survey / "b") not in r.stdout
    assert len({row["session"] for row in rows(tmp_path / "o" / "trajectory.csv")}) == 1  # b alone, mapped
