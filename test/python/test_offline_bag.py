"""offline_slam --bag: two dives as bags (folder_to_bag's, one raw, one PNG-compressed, the sensor mounts
in /tf_static) give the keyframes, poses and one map the same dives give as folders, deterministically,
faster than real time with progress; a bag without a topic, a camera_info, a mount, an empty and a
truncated bag fail with one line naming what is missing and the option that gives it."""
import math
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import rosbag
import rospy
import yaml
from geometry_msgs.msg import TransformStamped
from tf2_msgs.msg import TFMessage
from tool_runner import TWO_DIVES, make_survey, read_csv as rows, run_tool as run

STAMP = 1700000000  # folder_to_bag's default start time
EVALUATE = str(Path(__file__).resolve().parents[2] / "src" / "tools" / "evaluate.py")


def add_mounts(bag_path):
    """/tf_static as robot_state_publisher records it: base_link -> camera (optical: looking down, image
    columns along x) and -> altimeter, both at base_link's origin (the mount folder_to_bag's nav assumes)."""
    def transform(child, q):
        t = TransformStamped()
        t.header.stamp = rospy.Time(STAMP)
        t.header.frame_id, t.child_frame_id = "base_link", child
        t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z, t.transform.rotation.w = q
        return t
    with rosbag.Bag(str(bag_path), "a") as bag:
        msg = TFMessage([transform("camera", (1, 0, 0, 0)), transform("altimeter", (0, 0, 0, 1))])
        bag.write("/tf_static", msg, rospy.Time(STAMP))


@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    spec = yaml.safe_load(TWO_DIVES)
    spec["sessions"][0]["nav"] = {"enabled": True}  # the first dive's bag carries /nav/odom
    return make_survey(tmp_path_factory.mktemp("bag"), yaml.safe_dump(spec))


def to_bag(survey, name, path, *args):
    r = run("folder_to_bag", survey / name, path, *args)
    assert r.returncode == 0, r.stderr
    return path


@pytest.fixture(scope="module")
def bags(survey, tmp_path_factory):
    base = tmp_path_factory.mktemp("bags")
    a = to_bag(survey, "a", base / "a.bag")
    b = to_bag(survey, "b", base / "b.bag", "--image-format", "png")
    shutil.copy(a, base / "a_no_mount.bag")
    add_mounts(a)
    add_mounts(b)
    return base


@pytest.fixture(scope="module")
def folders_run(survey, tmp_path_factory):
    out = tmp_path_factory.mktemp("folders")
    r = run("offline_slam", "--session", survey / "a", "--session", survey / "b", "--out", out)
    assert r.returncode == 0, r.stderr
    return out


@pytest.fixture(scope="module")
def bags_run(bags, tmp_path_factory):
    out = tmp_path_factory.mktemp("bags_out")
    r = run("offline_slam", "--bag", bags / "a.bag", "--bag", bags / "b.bag", "--out", out)
    assert r.returncode == 0, r.stderr
    return out, r.stdout


def keyframes(out):
    return {(t["session"], t["index"]): t for t in rows(out / "trajectory.csv")}


def test_bags_give_the_keyframes_poses_and_one_map_of_the_folders(folders_run, bags_run):
    out, _ = bags_run
    folder, bag = keyframes(folders_run), keyframes(out)
    common = folder.keys() & bag.keys()
    assert len(common) >= 0.95 * max(len(folder), len(bag)), (sorted(folder), sorted(bag))
    assert {t["map"] for t in bag.values()} == {"0"}  # the two dives joined into one map, as the folders
    assert {t["map"] for t in folder.values()} == {"0"}
    for k in common:
        f, b = folder[k], bag[k]
        # Only the altitude differs: a Range carries it as a float32.
        assert math.hypot(float(f["x_m"]) - float(b["x_m"]), float(f["y_m"]) - float(b["y_m"])) < 1e-3, k
        assert abs(float(f["yaw_rad"]) - float(b["yaw_rad"])) < 1e-3, k
    assert len(rows(out / "loops.csv")) >= 0.95 * len(rows(folders_run / "loops.csv"))


def test_evaluate_scores_the_bags_against_their_folders_as_the_folders(survey, folders_run, bags_run, tmp_path):
    """The run of both bags (its own inputs.csv) against the survey's folders: the folders' run's ATE and e_k."""
    scores = []
    for out in (folders_run, bags_run[0]):
        report = tmp_path / out.name
        r = subprocess.run([sys.executable, EVALUATE, "--run", str(out), "--mission", str(survey), "--report",
                            str(report), "--no-plots"], capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr
        scores.append({(m["scope"], m["id"], m["metric"]): m["value"] for m in rows(report / "metrics.csv")
                       if m["estimate"] == "slam"})
    folder, bag = scores
    for key in [("session", "0", "ate_rmse_m"), ("session", "1", "ate_rmse_m"), ("session", "0", "ek_inter_m"),
                ("map", "0", "ate_rmse_m"), ("map", "0", "ek_inter_m")]:
        assert folder[key] != "n/a" and float(bag[key]) == pytest.approx(float(folder[key]), abs=1e-3), key
    assert bag[("map", "0", "ek_inter_pairs")] == folder[("map", "0", "ek_inter_pairs")] != "0"


def test_the_nav_of_the_bag_is_read(bags_run):
    _, stdout = bags_run
    a = [line for line in stdout.splitlines() if line.startswith(str(_bag_name(stdout, "a.bag")) + ": 24 frames")]
    assert a and "nav readings of" in a[0] and "mount from /tf_static" in a[0], stdout


def _bag_name(stdout, name):
    return next(w.rstrip(":") for w in stdout.split() if w.endswith(name + ":"))


def test_progress_and_faster_than_real_time(bags_run):
    _, stdout = bags_run
    assert "100 % of the bag" in stdout and "frames/s" in stdout, stdout
    ratios = [float(line.split(": ")[-1].split("x")[0]) for line in stdout.splitlines() if "x real time" in line]
    assert len(ratios) == 2 and min(ratios) > 1.0, ratios


def test_the_same_outputs_again_with_the_mount_given_and_two_threads(bags, bags_run, tmp_path):
    out, _ = bags_run
    r = run("offline_slam", "--bag", bags / "a.bag", "--bag", bags / "b.bag", "--out", tmp_path, "--quiet",
            "--camera-mount", "0 0 0 0", "--threads", "2")
    assert r.returncode == 0, r.stderr
    for name in ("trajectory.csv", "odometry.csv", "loops.csv", "pieces.csv"):
        assert (tmp_path / name).read_text() == (out / name).read_text(), name


def test_a_namespaced_bag_needs_its_namespace(survey, tmp_path):
    topics = [("--image-topic", "camera/image_raw"), ("--camera-info-topic", "camera/camera_info"),
              ("--altitude-topic", "altitude")]
    args = [x for flag, t in topics for x in (flag, "/uw_multislam/" + t)]
    bag = to_bag(survey, "b", tmp_path / "ns.bag", "--no-nav", *args)
    r = run("offline_slam", "--bag", bag, "--out", tmp_path / "o1", "--camera-mount", "0 0 0 0")
    assert r.returncode == 1 and "/uw_multislam/camera/image_raw" in r.stderr and "--ns" in r.stderr, r.stderr
    r = run("offline_slam", "--bag", bag, "--out", tmp_path / "o2", "--camera-mount", "0 0 0 0", "--ns",
            "/uw_multislam", "--finish-after", "3")
    assert r.returncode == 0, r.stderr
    assert rows(tmp_path / "o2" / "pieces.csv"), r.stdout


def fails(*args, status=1):
    r = run("offline_slam", *args)
    assert r.returncode == status, (r.returncode, r.stdout, r.stderr)
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    return r.stderr


def test_a_bag_without_the_mounts_names_the_frame_and_the_option(bags, tmp_path):
    err = fails("--bag", bags / "a_no_mount.bag", "--out", tmp_path / "o")
    assert "base_link -> camera" in err and "/tf_static" in err and "--camera-mount" in err, err
    assert not (tmp_path / "o").exists()


def test_missing_topics_name_the_topic_and_the_option(bags, survey, tmp_path):
    err = fails("--bag", bags / "a.bag", "--out", tmp_path / "o", "--image-topic", "/cam/image_raw")
    assert "/cam/image_raw" in err and "/camera/image_raw" in err and "--image-topic" in err, err
    err = fails("--bag", bags / "a.bag", "--out", tmp_path / "o", "--altitude-topic", "dvl/range")
    assert "/dvl/range" in err and "--altitude-topic" in err, err
    no_info = to_bag(survey, "b", tmp_path / "no_info.bag", "--camera-info-topic", "/elsewhere/camera_info")
    err = fails("--bag", no_info, "--out", tmp_path / "o", "--camera-mount", "0 0 0 0")
    assert "no camera_info" in err and "/elsewhere/camera_info" in err and "--camera-info-topic" in err, err


def test_empty_truncated_and_missing_bags_fail_with_one_line(bags, tmp_path):
    empty = tmp_path / "empty.bag"
    rosbag.Bag(str(empty), "w").close()
    assert "empty" in fails("--bag", empty, "--out", tmp_path / "o")
    data = (bags / "a.bag").read_bytes()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[: len(data) // 2])
    assert "rosbag reindex" in fails("--bag", cut, "--out", tmp_path / "o")
    assert "no such bag" in fails("--bag", tmp_path / "none.bag", "--out", tmp_path / "o")
    assert not (tmp_path / "o").exists()


def test_bags_and_folders_are_not_mixed(bags, survey, tmp_path):
    assert "not mixed" in fails("--bag", bags / "a.bag", "--session", survey / "a", "--out", tmp_path, status=2)
    assert "numbers" in fails("--bag", bags / "a.bag", "--camera-mount", "0 0 0", "--out", tmp_path, status=2)


def test_a_bag_already_in_the_store_is_refused(bags, tmp_path):
    args = ["--bag", bags / "a.bag", "--db", tmp_path / "s.db", "--finish-after", "4", "--quiet"]
    r = run("offline_slam", *args, "--out", tmp_path / "o1")
    assert r.returncode == 0, r.stderr
    err = fails(*args, "--out", tmp_path / "o2", status=3)
    assert "a.bag is already in" in err and "--again" in err, err


def test_a_dvls_own_message_gives_the_altitude_its_range_gives(bags, tmp_path):
    """The bag's Ranges moved into nav_msgs/Odometry messages (pose.pose.position.z), a DVL driver's own
    type: read with --dvl-topic/--dvl-field, the outputs are those of the Ranges."""
    from nav_msgs.msg import Odometry
    dvl = tmp_path / "dvl.bag"
    with rosbag.Bag(str(bags / "a.bag")) as src, rosbag.Bag(str(dvl), "w") as dst:
        for topic, msg, t in src.read_messages():
            if topic != "/altitude":
                dst.write(topic, msg, t)
                continue
            o = Odometry()
            o.header = msg.header
            o.pose.pose.position.z = msg.range
            dst.write("/dvl/data", o, t)
    common = ["--out", tmp_path / "o", "--finish-after", "8", "--quiet", "--nav", "off"]
    r = run("offline_slam", "--bag", bags / "a.bag", *common)
    assert r.returncode == 0, r.stderr
    ranges = {n: (tmp_path / "o" / n).read_text() for n in ("trajectory.csv", "odometry.csv")}
    r = run("offline_slam", "--bag", dvl, *common, "--dvl-topic", "/dvl/data", "--dvl-field", "m.pose.pose.position.z")
    assert r.returncode == 0, r.stderr
    assert {n: (tmp_path / "o" / n).read_text() for n in ranges} == ranges
    assert len(rows(tmp_path / "o" / "trajectory.csv")) > 2
    err = fails("--bag", dvl, "--out", tmp_path / "o2", "--dvl-topic", "/dvl/data")
    assert "no field 'altitude'" in err and "pose" in err and "--dvl-field" in err, err


def test_a_dive_split_into_bags_reads_as_one(bags, tmp_path):
    """rosbag record --split: the halves named together (--bag a_0.bag,a_1.bag) give the whole bag's outputs."""
    parts = [tmp_path / "a_0.bag", tmp_path / "a_1.bag"]
    with rosbag.Bag(str(bags / "a.bag")) as src, rosbag.Bag(str(parts[0]), "w") as first, \
            rosbag.Bag(str(parts[1]), "w") as second:
        for topic, msg, t in src.read_messages():
            (first if t.to_sec() < STAMP + 4.5 or topic == "/tf_static" else second).write(topic, msg, t)
    common = ["--finish-after", "8", "--quiet"]
    r = run("offline_slam", "--bag", bags / "a.bag", "--out", tmp_path / "whole", *common)
    assert r.returncode == 0, r.stderr
    r = run("offline_slam", "--bag", "%s,%s" % tuple(parts), "--out", tmp_path / "split", *common)
    assert r.returncode == 0, r.stderr
    for name in ("trajectory.csv", "odometry.csv", "loops.csv"):
        assert (tmp_path / "split" / name).read_text() == (tmp_path / "whole" / name).read_text(), name
    assert max(int(t["index"]) for t in rows(tmp_path / "split" / "trajectory.csv")) > 4  # keyframes after the split
    err = fails("--bag", "%s,%s" % (parts[0], tmp_path / "gone.bag"), "--out", tmp_path / "o")
    assert "gone.bag: no such bag" in err, err
