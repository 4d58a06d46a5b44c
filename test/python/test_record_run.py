"""record_run.py's conversion of the published vehicle poses (base_link, z-up map) back to the
core's camera poses (image axes), against an independent 3-D chain of 4x4 transforms."""
import importlib.util
import math
import os

import numpy as np

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
