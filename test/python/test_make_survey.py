"""make_survey end to end: command line, dataset folders, ground truth and the bags it writes."""
import importlib.util
import json
import math
import os
import subprocess

import pytest
import rosbag
import yaml
from tool_runner import read_csv, run_tool

TINY = """
seed: 4
world: {width_m: 5, height_m: 4, metres_per_px: 0.01}
sessions:
  - name: first
    camera: {image_width: 96, image_height: 72, fx: 90, fy: 90, cx: 47.5, cy: 35.5}
    image_format: png
    mission: {pattern: out_and_back, start_m: [1.2, 1.5], length_m: 1.5, leg_spacing_m: 0.4,
              speed_m_s: 0.25, frame_period_s: 1.0, altitude_m: 1.2}
  - name: second
    camera: {image_width: 96, image_height: 72, fx: 90, fy: 90, cx: 47.5, cy: 35.5}
    mission: {pattern: loop, start_m: [3.0, 2.0], heading_rad: 1.5708, length_m: 1.2, width_m: 0.8,
              laps: 1.0, speed_m_s: 0.3, frame_period_s: 0.5, altitude_m: 1.3}
    water: {illumination: 0.6, turbidity_per_m: 0.1}
"""


def run(*args):
    return run_tool("make_survey", *args, timeout=120)


@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    base = tmp_path_factory.mktemp("survey")
    config = base / "tiny.yaml"
    config.write_text(TINY)
    out = base / "out"
    result = run("--config", str(config), "--out", str(out), "--quiet")
    assert result.returncode == 0, result.stderr
    return out, result


def test_help_and_bad_arguments():
    r = run("--help")
    assert r.returncode == 0 and "--preset" in r.stdout and "loops_gt.csv" in r.stdout
    r = run("--frobnicate")
    assert r.returncode == 2 and "unknown argument" in r.stderr
    r = run("--preset", "nope", "--out", "/tmp/uwms_never_written")
    assert r.returncode == 1 and "unknown preset 'nope'" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert not os.path.exists("/tmp/uwms_never_written")
    # Seeds past 2^64 - 1 were clamped to it by strtoull (two seeds, one survey); negative, empty
    # and trailing text refused as before.
    for seed in ("18446744073709551616", "99999999999999999999999", "-1", " -1", " 7", "+7", "", "7x"):
        r = run("--preset", "demo", "--seed", seed, "--out", "/tmp/uwms_never_written")
        assert r.returncode == 2 and "bad seed '%s'" % seed in r.stderr, (seed, r.stderr)
    assert not os.path.exists("/tmp/uwms_never_written")


def test_bad_config_names_the_key(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("sessions: [{mission: {patern: loop}}]\n")
    r = run("--config", str(bad), "--out", str(tmp_path / "o"))
    assert r.returncode == 1
    assert "unknown key 'patern'" in r.stderr and str(bad) in r.stderr


def test_presets_are_listed_and_dumpable():
    names = run("--list-presets").stdout.split()
    assert "demo" in names and "blank" in names
    spec = yaml.safe_load(run("--preset", "demo", "--dump-config").stdout)
    assert [s["name"] for s in spec["sessions"]] == ["s0", "s1"]
    assert spec["sessions"][1]["water"]["illumination"] < spec["sessions"][0]["water"]["illumination"]


def test_writes_folders_and_mission_ground_truth(survey):
    out, result = survey
    assert "2 sessions" in result.stdout
    world = read_csv(out / "world_gt.csv")
    for s, name in enumerate(["first", "second"]):
        frames = read_csv(out / name / "frames.csv")
        gt = read_csv(out / name / "gt.csv")
        assert len(frames) == len(gt) > 4
        assert sum(1 for w in world if int(w["session"]) == s) == len(frames)
        for f in frames:
            assert (out / name / f["image"]).is_file()
        assert float(gt[0]["x_m"]) == 0.0 and float(gt[0]["y_m"]) == 0.0
    assert (out / "first" / "0000.png").is_file() and (out / "second" / "0000.jpg").is_file()
    with open(out / "loops_gt.csv") as f:
        assert f.readline().strip() == "session_a,index_a,session_b,index_b"
    assert len(read_csv(out / "loops_gt.csv")) > 0  # the out-and-back passes over itself


def test_bag_holds_the_expected_topics_counts_and_values(survey):
    out, _ = survey
    frames = read_csv(out / "first" / "frames.csv")
    gt = read_csv(out / "first" / "gt.csv")
    with rosbag.Bag(str(out / "first.bag")) as bag:
        info = bag.get_type_and_topic_info().topics
        assert info["/camera/image_raw"].msg_type == "sensor_msgs/Image"
        assert info["/camera/camera_info"].msg_type == "sensor_msgs/CameraInfo"
        assert info["/altitude"].msg_type == "sensor_msgs/Range"
        assert info["/ground_truth/odom"].msg_type == "nav_msgs/Odometry"
        for topic in info:
            assert info[topic].message_count == len(frames), topic
        ranges = [m.range for _, m, _ in bag.read_messages(topics=["/altitude"])]
        assert ranges == pytest.approx([float(f["altitude_m"]) for f in frames], abs=1e-4)
        images = [m for _, m, _ in bag.read_messages(topics=["/camera/image_raw"])]
        assert images[0].encoding == "bgr8" and (images[0].width, images[0].height) == (96, 72)
        odom = [m for _, m, _ in bag.read_messages(topics=["/ground_truth/odom"])]
        last, ref = odom[-1].pose.pose, gt[-1]
        assert last.position.x == pytest.approx(float(ref["x_m"]), abs=1e-5)
        yaw_error = 2 * math.atan2(last.orientation.z, last.orientation.w) - float(ref["yaw_rad"])
        assert math.atan2(math.sin(yaw_error), math.cos(yaw_error)) == pytest.approx(0.0, abs=1e-5)
        stamps = [m.header.stamp.to_sec() for m in images]
        assert all(b > a for a, b in zip(stamps, stamps[1:]))


def test_effective_spec_reproduces_the_survey(survey, tmp_path):
    out, _ = survey
    again = tmp_path / "again"
    r = run("--config", str(out / "survey.yaml"), "--out", str(again), "--no-bag", "--quiet")
    assert r.returncode == 0, r.stderr
    for name in ["first", "second"]:
        for f in ["frames.csv", "gt.csv", "0003.png" if name == "first" else "0003.jpg"]:
            assert (again / name / f).read_bytes() == (out / name / f).read_bytes(), f
    assert not (again / "first.bag").exists()


def test_progress_in_a_log_is_a_few_whole_lines(survey, tmp_path):
    """stderr is a pipe here, as in a log: no carriage returns, a line per 10 % of each session,
    ending at its last frame (progress was one huge line)."""
    out, _ = survey
    config = tmp_path / "tiny.yaml"
    config.write_text(TINY)
    result = run("--config", str(config), "--out", str(tmp_path / "again"), "--no-bag")
    assert result.returncode == 0, result.stderr
    assert "\r" not in result.stderr
    lines = [line for line in result.stderr.splitlines() if line.startswith("rendering ")]
    for name in ("first", "second"):
        frames = len(read_csv(out / name / "frames.csv"))
        mine = [line for line in lines if line.startswith("rendering %s: " % name)]
        assert mine[-1] == "rendering %s: %d/%d" % (name, frames, frames)
        assert len(mine) == len(set(mine)) and len(mine) <= 11, mine


def test_the_readme_mosaic_mission_flies_inside_the_imaged_reef(tmp_path):
    """README's mosaic example (the one it showed left the mosaic and was refused)."""
    repo = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")
    data = os.path.join(repo, "..", "shared", "data", "acfr", "test4")
    result = run("--config", os.path.join(repo, "config", "missions", "acfr_test4_mosaic.yaml"), "--mosaic",
                 os.path.join(data, "mosaic.jpg"), os.path.join(data, "mosaic.txt"), "--out", str(tmp_path / "m"),
                 "--no-bag", "--quiet")
    assert result.returncode == 0, result.stderr
    assert len(read_csv(tmp_path / "m" / "s0" / "frames.csv")) == 28


def test_a_survey_with_lens_distortion_is_scored_by_evaluate(tmp_path):
    """make_survey --distortion writes camera.yaml as a ROS calibration YAML (doc/dataset_format.md);
    offline_slam runs on it and evaluate.py scores the run, its camera read from K."""
    config = tmp_path / "tiny.yaml"
    config.write_text(TINY)
    mission = tmp_path / "m"
    r = run("--config", config, "--out", mission, "--distortion", "-0.08,0.01", "--no-bag", "--quiet")
    assert r.returncode == 0, r.stderr
    calibration = yaml.safe_load((mission / "first" / "camera.yaml").read_text())
    assert "camera_matrix" in calibration and calibration["distortion_model"] == "plumb_bob"
    r = run_tool("offline_slam", "--session", mission / "first", "--session", mission / "second", "--out",
                 tmp_path / "run", "--quiet")
    assert r.returncode == 0, r.stderr
    evaluate = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "src", "tools", "evaluate.py")
    report = tmp_path / "report"
    e = subprocess.run(["/usr/bin/python3", evaluate, "--run", tmp_path / "run", "--mission", mission, "--report",
                        report, "--no-plots"], capture_output=True, text=True, timeout=300)
    assert e.returncode == 0, e.stderr
    metrics = json.loads((report / "metrics.json").read_text())["session"]["0"]["odometry"]
    keyframes = [row for row in read_csv(tmp_path / "run" / "odometry.csv") if row["session"] == "0"]
    assert metrics["n_keyframes"] == len(keyframes) > 2
    # The footprint (image_height * altitude / fy) is what loop correctness is judged by: K's fy.
    k = calibration["camera_matrix"]["data"]
    spec = importlib.util.spec_from_file_location("evaluate", evaluate)
    ev = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ev)
    camera = ev.read_camera_yaml(str(mission / "first" / "camera.yaml"))
    assert (camera["fx"], camera["fy"], camera["cx"], camera["cy"]) == (k[0], k[4], k[2], k[5])
    assert (camera["image_width"], camera["image_height"]) == (calibration["image_width"], calibration["image_height"])
