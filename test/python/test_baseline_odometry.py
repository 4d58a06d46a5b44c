"""baseline_odometry, the naive odometer of the benchmarks (OpenCV SIFT + ratio test +
estimateAffinePartial2D from frame to frame): on a small generated survey every pair gives a motion;
an unreadable frame is counted, fails the two pairs it is in, and the pose is held through them."""
import shutil

import pytest
from test_offline_slam import SURVEY
from tool_runner import make_survey, read_csv as rows, run_tool as run


@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    return make_survey(tmp_path_factory.mktemp("baseline"), SURVEY)


def baseline(folder, out):
    r = run("baseline_odometry", "--session", folder, "--out", out)
    assert r.returncode == 0, r.stderr
    (line,) = [x for x in r.stdout.splitlines() if x.startswith("baseline session 0 ")]
    return line, [(float(p["x_m"]), float(p["y_m"]), float(p["yaw_rad"])) for p in rows(out / "odometry.csv")]


def test_every_pair_of_a_clean_folder_gives_a_motion(survey, tmp_path):
    line, poses = baseline(survey / "a", tmp_path / "out")
    n = len(rows(survey / "a" / "frames.csv"))
    assert "%d frames (0 unreadable), 0 of %d pairs failed" % (n, n - 1) in line, line
    assert len(poses) == n
    # The vehicle moves between frames (0.4 m/s, one frame a second): no pose is held.
    assert all(abs(b[0] - a[0]) + abs(b[1] - a[1]) > 0.1 for a, b in zip(poses, poses[1:])), poses


def test_an_unreadable_frame_is_counted_and_the_pose_held(survey, tmp_path):
    folder = tmp_path / "a"
    shutil.copytree(survey / "a", folder)
    frames = rows(folder / "frames.csv")
    k = 5
    (folder / frames[k]["image"]).write_bytes(b"not an image")
    line, poses = baseline(folder, tmp_path / "out")
    n = len(frames)
    assert "%d frames (1 unreadable), 2 of %d pairs failed" % (n, n - 1) in line, line
    assert poses[k] == poses[k - 1] and poses[k + 1] == poses[k], poses[k - 1:k + 2]
    assert poses[k + 2] != poses[k + 1]  # tracking goes on from the next readable pair
