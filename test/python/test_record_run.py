"""record_run.py's conversion of the published vehicle poses (base_link, z-up map) back to the
core's camera poses (image axes), against an independent 3-D chain of 4x4 transforms; and its
placement of keyframes in the --session-dir folders by stamp (one --bag-start per folder)."""
import importlib.util
import math
import os
import threading
import time

import numpy as np
import pytest
import rospy

TOOL = os.path.join(os.path.dirname(__file__), "..", "..", "src", "tools", "record_run.py")
_spec = importlib.util.spec_from_file_location("record_run", TOOL)
rr = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(rr)


def rot_x(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


def planar(x, y, z, yaw):
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0, x], [s, c, 0, y], [0, 0, 1, z], [0, 0, 0, 1.0]])


def test_camera_pose_inverts_the_chain_map_base_camera():
    rng = np.random.default_rng(5)
    for _ in range(100):
        x, y, yaw = rng.uniform(-20, 20), rng.uniform(-20, 20), rng.uniform(-3, 3)
        mount = (rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-3, 3))
        # tf: map <- base_link, base_link <- camera optical (level frame turned by pi about x); the
        # core's frame S is the map turned by pi about x, so S <- optical = rot_x(pi)^-1 map <- optical.
        map_from_optical = planar(x, y, 0, yaw) @ planar(mount[0], mount[1], 0, mount[2]) @ rot_x(math.pi)
        s_from_optical = np.linalg.inv(rot_x(math.pi)) @ map_from_optical
        assert abs(s_from_optical[2, 2] - 1.0) < 1e-12  # the optical axis is S's z: a planar pose
        got = rr.camera_pose(x, y, yaw, mount)
        assert abs(got[0] - s_from_optical[0, 3]) < 1e-9
        assert abs(got[1] - s_from_optical[1, 3]) < 1e-9
        expected_yaw = math.atan2(s_from_optical[1, 0], s_from_optical[0, 0])
        assert abs(math.remainder(got[2] - expected_yaw, 2 * math.pi)) < 1e-12


def test_default_mount_is_the_flip_of_y_and_yaw():
    assert rr.camera_pose(2.0, -1.0, -0.3, (0.0, 0.0, 0.0)) == (2.0, 1.0, 0.3)


# --- placing keyframes by stamp in the --session-dir folders (no ROS master) ---

def write_folder(root, name, stamps, header="index,image,stamp_s,altitude_m"):
    folder = os.path.join(str(root), name)
    os.makedirs(folder)
    with open(os.path.join(folder, "frames.csv"), "w") as f:
        f.write(header + "\n")
        for k, t in enumerate(stamps):
            f.write("%d,%04d.png,%.3f,1.5\n" % (k, k, t))
    return folder


def test_one_bag_start_per_folder_places_overlapping_folders(tmp_path):
    # Both folders start at stamp_s 0 (the shared flight folders); their bags were written with
    # folder_to_bag --start-time 1700000000 and 1700003600.
    a = write_folder(tmp_path, "a", [0.0, 1.0, 2.0])
    b = write_folder(tmp_path, "b", [0.0, 1.0, 2.0, 3.0])
    table = rr.read_frame_stamps([a, b], [1700000000.0, 1700003600.0])
    assert table[rr.stamp_key(1700000001.0)] == (0, 1)
    assert table[rr.stamp_key(1700003601.0)] == (1, 1)
    assert table[rr.stamp_key(1700003603.0)] == (1, 3)
    assert len(table) == 7


def test_one_bag_start_for_all_folders_with_distinct_stamps(tmp_path):
    a = write_folder(tmp_path, "a", [0.0, 1.0])
    b = write_folder(tmp_path, "b", [86400.0, 86401.0])  # make_survey's second mission, a day later
    for starts in ([], [1700000000.0]):
        table = rr.read_frame_stamps([a, b], starts)
        assert table[rr.stamp_key(1700086401.0)] == (1, 1)
        assert table[rr.stamp_key(1700000000.0)] == (0, 0)


def test_overlapping_folders_with_one_start_name_both_folders_and_the_fix(tmp_path):
    a = write_folder(tmp_path, "flight_a", [0.0, 1.0])
    b = write_folder(tmp_path, "flight_b", [0.0, 1.0])
    with pytest.raises(ValueError) as e:
        rr.read_frame_stamps([a, b], [1700000000.0])
    assert a in str(e.value) and b in str(e.value)
    assert "--bag-start once per --session-dir" in str(e.value)


@pytest.mark.parametrize("header, rows, why", [
    ("index,image,stamp_s,altitude_m", "0,0000.png,0.0,1.5\n1,0001.png,0.0,1.5\n", "frames 0 and 1 have the same stamp"),
    ("index,image,altitude_m", "0,0000.png,1.5\n", "no column stamp_s"),
    ("index,image,stamp_s,altitude_m", "0,0000.png,soon,1.5\n", ":2: cannot read index '0' / stamp_s 'soon'"),
    ("index,image,stamp_s,altitude_m", "", "no frames"),
])
def test_every_error_names_the_folder(tmp_path, header, rows, why):
    folder = os.path.join(str(tmp_path), "dive")
    os.makedirs(folder)
    with open(os.path.join(folder, "frames.csv"), "w") as f:
        f.write(header + "\n" + rows)
    with pytest.raises(ValueError) as e:
        rr.read_frame_stamps([folder], [])
    assert os.path.join(folder, "frames.csv") in str(e.value)
    assert why in str(e.value)


def test_missing_folder_and_wrong_number_of_starts_are_named(tmp_path):
    a = write_folder(tmp_path, "a", [0.0])
    with pytest.raises(ValueError, match="no_such_dir: --session-dir is not a folder"):
        rr.read_frame_stamps([a, os.path.join(str(tmp_path), "no_such_dir")], [])
    b = write_folder(tmp_path, "b", [0.0])
    c = write_folder(tmp_path, "c", [0.0])
    with pytest.raises(ValueError) as e:
        rr.read_frame_stamps([a, b, c], [1.0, 2.0])
    assert "2 --bag-start values for 3 --session-dir folders" in str(e.value) and c in str(e.value)


def test_unplaced_keyframes_are_counted_and_placed_ones_keep_the_folder(tmp_path):
    a = write_folder(tmp_path, "a", [0.0, 1.0])
    b = write_folder(tmp_path, "b", [0.0, 1.0])
    table = rr.read_frame_stamps([a, b], [100.0, 200.0])
    recorder = rr.Recorder.__new__(rr.Recorder)  # placement only: no subscribers, no master
    recorder.frame_stamps, recorder.unplaced, recorder.describe_folders = table, 0, rr.stamp_ranges([a, b], table)
    assert "a: 100.000..101.000" in recorder.describe_folders and "b: 200.000..201.000" in recorder.describe_folders
    assert recorder.place(7, 3, rospy.Time(201)) == (1, 1)  # ROS session 7 (a tracking loss) in folder 1
    assert recorder.place(7, 4, rospy.Time(150)) is None
    assert recorder.unplaced == 1


def test_inputs_csv_is_what_evaluate_checks_the_folders_against(tmp_path):
    _spec_ev = importlib.util.spec_from_file_location(
        "evaluate", os.path.join(os.path.dirname(TOOL), "evaluate.py"))
    ev = importlib.util.module_from_spec(_spec_ev)
    _spec_ev.loader.exec_module(ev)
    a = write_folder(tmp_path, "a", [0.0, 1.0, 2.5])
    b = write_folder(tmp_path, "b", [4.0, 5.0])
    with open(os.path.join(b, "frames.csv"), "a") as f:
        f.write("2,0002.png,6.0,nan\n3,0003.png,7.0,2.5\n")  # an altitude missing: left out of the mean
    recorder = rr.Recorder(rr.RunFiles(str(tmp_path / "run")), None, inputs=rr.run_inputs([a, b]))
    recorder.finish()
    rows = ev.read_table(str(tmp_path / "run" / "inputs.csv"), ev.INPUTS_COLUMNS)
    assert [(r["session"], r["folder"], r["frames"]) for r in rows] == [(0, a, 3), (1, b, 4)]
    assert rows[1]["altitude_mean_m"] == pytest.approx((1.5 + 1.5 + 2.5) / 3)
    for row, folder in zip(rows, (a, b)):
        frames = rr.read_frames(folder)
        truth = ev.SessionTruth(folder, {}, {k: alt for k, _, alt in frames}, {}, [t for _, t, _ in frames])
        made = (row["frames"], row["first_stamp_s"], row["last_stamp_s"], row["altitude_mean_m"])
        assert ev.same_summary(made, ev.folder_summary(truth))
    truth_a = ev.SessionTruth(a, {}, {k: alt for k, _, alt in rr.read_frames(a)}, {}, [t for _, t, _ in rr.read_frames(a)])
    other = (rows[1]["frames"], rows[1]["first_stamp_s"], rows[1]["last_stamp_s"], rows[1]["altitude_mean_m"])
    assert not ev.same_summary(other, ev.folder_summary(truth_a))


def test_until_idle_counts_from_the_last_message_once_a_keyframe_came(tmp_path):
    recorder = rr.Recorder.__new__(rr.Recorder)
    recorder.lock, recorder.keyframes, recorder.last_message = threading.Lock(), {}, time.time() - 100.0
    assert recorder.idle_for() == 0.0  # a latched path before the bag plays does not start the count
    recorder.keyframes[(0, 0)] = {}
    assert 99.0 < recorder.idle_for() < 110.0


def test_pieces_of_a_split_folder_and_their_map_labels_follow_offline_slam():
    """ROS sessions 3, 4 (folder 0, split by a tracking loss), 5 (folder 1), 7 (folder 0 again):
    pieces 0, 1, 0, 2; the first piece of a folder names its map by the folder, later pieces by
    the next numbers no folder uses (2, 3), as core::writeRunOutputs labels them."""
    piece, label = rr.pieces_and_map_labels({3: 0, 4: 0, 5: 1, 7: 0})
    assert piece == {3: 0, 4: 1, 5: 0, 7: 2}
    assert label == {3: 0, 4: 2, 5: 1, 7: 3}
    assert rr.pieces_and_map_labels({}) == ({}, {})


# --- the files written as the messages come (no ROS master: the callbacks called directly) ---

def keyframe(session, k, stamp):
    from uw_multislam.msg import Keyframe
    m = Keyframe(session=session, keyframe=k, frame_index=k)
    m.header.stamp = rospy.Time(stamp)
    m.odometry_pose.x, m.odometry_pose.y, m.odometry_pose.theta = 0.5 * k, -0.25 * k, 0.01 * k
    return m


def loop(session_a, ka, session_b, kb, stamp):
    from uw_multislam.msg import Loop
    m = Loop(kind=Loop.LOCAL if session_a == session_b else Loop.GLOBAL, session_a=session_a, keyframe_a=ka,
             session_b=session_b, keyframe_b=kb, inliers=40 + kb)
    m.header.stamp = rospy.Time(stamp)
    m.pose.x, m.pose.y, m.pose.theta = 0.1, 0.2, 0.03
    return m


def rows(path):
    with open(path) as f:
        return f.read().splitlines()


def test_rows_are_on_disk_as_each_message_comes(tmp_path):
    """Nothing waits for the end: each keyframe's odometry row and each loop's rows are in the files
    (flushed) when the callback returns; a loop that names a keyframe not received yet is written
    once it comes; the path's trajectory rows at the next refresh. An earlier run's files in OUT are
    replaced at the start."""
    out = tmp_path / "run"
    out.mkdir()
    (out / "trajectory.csv").write_text("session,index,map,x_m,y_m,yaw_rad\n9,9,9,0,0,0\n")
    (out / "odometry.csv").write_text("session,index,x_m,y_m,yaw_rad\n9,9,0,0,0\n")
    recorder = rr.Recorder(rr.RunFiles(str(out)), None)
    assert rows(out / "trajectory.csv") == ["session,index,map,x_m,y_m,yaw_rad"]
    assert rows(out / "odometry.csv") == ["session,index,x_m,y_m,yaw_rad"]
    for k in range(3):
        recorder.on_keyframe(keyframe(0, k, 100 + k))
        assert rows(out / "odometry.csv")[1:] == ["0,%d,%.6f,%.6f,%.7f" % (i, 0.5 * i, -0.25 * i, 0.01 * i)
                                                  for i in range(k + 1)]
    recorder.on_keyframe(keyframe(0, 2, 102))  # sent twice: one row
    assert len(rows(out / "odometry.csv")) == 4
    recorder.on_loop(loop(0, 0, 0, 2, 102))
    recorder.on_loop(loop(0, 1, 0, 3, 103))  # keyframe 3 has not come yet
    assert rows(out / "loops.csv")[1:] == ["0,0,0,2,local,42"]
    assert rows(out / "loop_poses.csv")[1:] == ["0,0,0,2,0.100000,0.200000,0.0300000"]
    recorder.on_keyframe(keyframe(0, 3, 103))
    assert rows(out / "loops.csv")[1:] == ["0,0,0,2,local,42", "0,1,0,3,local,43"]
    from nav_msgs.msg import Path
    from geometry_msgs.msg import PoseStamped
    path = Path(poses=[PoseStamped() for _ in range(4)])
    for k, p in enumerate(path.poses):
        p.header.stamp, p.pose.position.x, p.pose.orientation.w = rospy.Time(100 + k), 1.0 * k, 1.0
    recorder.on_path(0, path)
    recorder.refresh(force=True)
    assert [r.split(",")[:4] for r in rows(out / "trajectory.csv")[1:]] == [["0", str(k), "0", "%.6f" % k]
                                                                          for k in range(4)]
    assert rows(out / "pieces.csv")[1:] == ["0,0,0,0,3,4,0"]
    assert recorder.finish() == {"odometry": 4, "trajectory": 4, "loops": 2, "missing": 0}


def test_trajectory_is_replaced_at_most_once_a_period_while_it_changes(tmp_path):
    recorder = rr.Recorder(rr.RunFiles(str(tmp_path / "run")), None)
    from nav_msgs.msg import Path
    from geometry_msgs.msg import PoseStamped
    recorder.on_keyframe(keyframe(0, 0, 100))
    recorder.on_path(0, Path(poses=[PoseStamped()]))
    recorder.replaced_at = time.time()  # just replaced: the next change waits for the period
    recorder.refresh()
    assert rows(tmp_path / "run" / "trajectory.csv") == ["session,index,map,x_m,y_m,yaw_rad"]
    recorder.replaced_at -= rr.Recorder.REPLACE_PERIOD_S
    recorder.refresh()
    assert len(rows(tmp_path / "run" / "trajectory.csv")) == 2
    before = os.stat(tmp_path / "run" / "trajectory.csv").st_mtime_ns
    recorder.replaced_at -= rr.Recorder.REPLACE_PERIOD_S
    recorder.refresh()  # nothing changed since: not written again
    assert os.stat(tmp_path / "run" / "trajectory.csv").st_mtime_ns == before
    assert [n for n in os.listdir(tmp_path / "run") if n.endswith(".tmp")] == []
