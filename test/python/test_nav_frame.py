"""The nav's world frame (nav_frame.yaml, doc/dataset_format.md) end to end: make_survey writes one
mission's nav in gt.csv's frame, in ENU and in NED; the NED nav.csv is the ENU one mirrored as
REP-103 says, and offline_slam --nav on gives the same map from all three (the reader turns each
into the same camera motions). A bad nav_frame.yaml stops the run with one line naming the key."""
import math
import shutil

import pytest
from tool_runner import make_survey, read_csv as rows, run_tool as run

# A short out-and-back with a black-out across its turn: the nav carries the blind frames, so a
# mirrored reading (lateral steps and turns of the wrong sign) could not give the same map.
MISSION = """
seed: 21
nav_datum: {{name: site, origin_lat_lon_deg: [43.1, 5.9]}}
world: {{width_m: 12, height_m: 8, featureless_fraction: 0}}
sessions:
  - name: a
    camera: {{image_width: 240, image_height: 180, fx: 220, fy: 220, cx: 119.5, cy: 89.5}}
    mission: {{pattern: out_and_back, start_m: [3, 3], length_m: 5, leg_spacing_m: 1.0, speed_m_s: 0.4,
               frame_period_s: 1.0, altitude_m: 2.0}}
    water: {{stretches: [{{first_frame: 11, num_frames: 6, kind: blank}}]}}
    nav: {{enabled: true, frame: {frame}}}
"""


@pytest.fixture(scope="module")
def missions(tmp_path_factory):
    return {frame: make_survey(tmp_path_factory.mktemp(frame), MISSION.format(frame=frame))
            for frame in ("session", "enu", "ned")}


def nav_rows(mission):
    return [{k: float(v) for k, v in r.items()} for r in rows(mission / "a" / "nav.csv")]


def test_make_survey_writes_the_frame_and_ned_is_enu_mirrored(missions):
    assert not (missions["session"] / "a" / "nav_frame.yaml").exists()
    for frame in ("enu", "ned"):
        text = (missions[frame] / "a" / "nav_frame.yaml").read_text()
        assert "name: site\n" in text and f"convention: {frame}\n" in text
        assert "latitude_deg: 43.1\n" in text and "longitude_deg: 5.9\n" in text
    enu, ned = nav_rows(missions["enu"]), nav_rows(missions["ned"])
    assert len(enu) == len(ned) == len(rows(missions["enu"] / "a" / "frames.csv"))
    for e, n in zip(enu, ned):
        assert n["x_m"] == pytest.approx(e["y_m"], abs=2e-6) and n["y_m"] == pytest.approx(e["x_m"], abs=2e-6)
        assert math.remainder(n["yaw_rad"] - (math.pi / 2 - e["yaw_rad"]), math.tau) == pytest.approx(0, abs=2e-7)
        assert n["sigma_xy_m"] == e["sigma_xy_m"]
    # ENU is world_gt.csv as a north-up chart: east = x, north = -y; the nav starts at the truth.
    world = rows(missions["enu"] / "world_gt.csv")[0]
    assert enu[0]["x_m"] == pytest.approx(float(world["x_m"]), abs=2e-6)
    assert enu[0]["y_m"] == pytest.approx(-float(world["y_m"]), abs=2e-6)


def slam(mission, out):
    r = run("offline_slam", "--session", mission / "a", "--out", out, "--nav", "on")
    assert r.returncode == 0, r.stderr
    return {(t["session"], t["index"]): (float(t["x_m"]), float(t["y_m"]), float(t["yaw_rad"]))
            for t in rows(out / "trajectory.csv")}, r.stdout


def test_the_same_map_from_a_nav_in_the_session_frame_in_enu_and_in_ned(missions, tmp_path):
    maps = {}
    for frame, mission in missions.items():
        maps[frame], out = slam(mission, tmp_path / frame)
        assert "frames carried by the nav" in out, out  # the nav did carry the blind frames
    worst = 0.0
    for frame in ("enu", "ned"):
        assert set(maps[frame]) == set(maps["session"]), frame
        for key, p in maps[frame].items():
            q = maps["session"][key]
            worst = max(worst, math.hypot(p[0] - q[0], p[1] - q[1]))
    print(f"\nlargest keyframe difference from the session-frame nav's map: {worst * 1000:.4f} mm")
    assert worst < 1e-4  # nav.csv's 6 decimals, not a mirrored motion (metres)


@pytest.mark.parametrize("text,needle", [
    ("name: site\nconvention: nwu\n", "nav_frame.yaml: nav_frame: convention 'nwu' is not enu or ned"),
    ("convention: enu\n", "missing key 'name'"),
    ("name: site\nconvention: enu\nlatitude_deg: 43.1\n", "'latitude_deg' without 'longitude_deg'"),
])
def test_a_bad_nav_frame_stops_the_run_naming_the_key(missions, tmp_path, text, needle):
    shutil.copytree(missions["enu"] / "a", tmp_path / "a")
    (tmp_path / "a" / "nav_frame.yaml").write_text(text)
    r = run("offline_slam", "--session", tmp_path / "a", "--out", tmp_path / "o")
    assert r.returncode == 1 and needle in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and not (tmp_path / "o").exists()


def test_export_says_which_origin_and_does_not_take_the_nav_frames_datum(missions, tmp_path):
    """nav_frame.yaml's datum is the origin of nav.csv's world frame; offline_slam's map frame is its
    first keyframe's (the same trajectory.csv from every nav frame, above), so export_survey does not
    take the datum as the exports' origin: it says so, and which origin it used."""
    slam(missions["enu"], tmp_path / "run")
    r = run("export_survey", "--run", tmp_path / "run", "--out", tmp_path / "plain", "--no-mosaic")
    assert r.returncode == 0, r.stderr
    datum_line = [line for line in r.stdout.splitlines() if line.startswith("origin: ")]
    assert len(datum_line) == 1, r.stdout
    assert "origin: none (no --origin: no GeoJSON, no GeoTIFF); " in datum_line[0]
    assert "nav_frame.yaml has a datum (43.1000000, 5.9000000), the origin of nav.csv's frame 'site'" in datum_line[0]
    assert not list((tmp_path / "plain").glob("*.geojson"))
    r = run("export_survey", "--run", tmp_path / "run", "--out", tmp_path / "geo", "--no-mosaic",
            "--origin", "43.2,5.8,90")
    assert r.returncode == 0, r.stderr
    assert "origin: --origin 43.2000000, 5.8000000, map x axis heading 90.0 deg\n" in r.stdout
    assert list((tmp_path / "geo").glob("*.geojson"))


@pytest.mark.parametrize("second", ["enu", "ned"])
def test_a_folder_in_the_same_named_frame_is_placed_whatever_its_convention(missions, tmp_path, second):
    """Two folders whose nav_frame.yaml name the frame 'site': the second is placed by the nav against
    the first (one nav_placements.csv row, folder 1's first keyframe against folder 0) whether its
    nav.csv is written ENU or NED: both are read into one frame, so the convention is how the rows are
    written, not another frame."""
    out = tmp_path / "run"
    r = run("offline_slam", "--session", missions["enu"] / "a", "--session", missions[second] / "a", "--out", out,
            "--nav", "on")
    assert r.returncode == 0, r.stderr
    placed = rows(out / "nav_placements.csv")
    assert [(p["session_a"], p["session_b"]) for p in placed] == [("0", "1")], r.stdout
    assert "placed by the nav in the nav's world frame site" in r.stdout
