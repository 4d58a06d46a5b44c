"""export_survey's contract (export_survey --help): on a store made by offline_slam --db from a small
generated two-session survey, the TUM files score like evaluate.py, the g2o files hold the store's
graph, the GeoJSON tracks sit where the origin puts them, and bad input gets a clear error with the
store left byte-identical."""
import hashlib
import json
import math
import os
import re
import shutil
import sqlite3
import struct

import numpy as np
import pytest
from test_offline_slam import SURVEY
from tool_runner import HERE, make_survey, read_csv as rows, run_tool as run

EVALUATE = os.path.join(HERE, "..", "..", "src", "tools", "evaluate.py")
ORIGIN = (43.2, 5.3, 30.0)  # lat, lon, heading of the map frame's x axis


@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    return make_survey(tmp_path_factory.mktemp("export_survey"), SURVEY)


@pytest.fixture(scope="module")
def store(survey, tmp_path_factory):
    base = tmp_path_factory.mktemp("store")
    db = base / "survey.db"
    r = run("offline_slam", "--session", survey / "a", "--session", survey / "b", "--out", base / "run", "--db", db,
            "--quiet")
    assert r.returncode == 0, r.stderr
    return db, base / "run"


def digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def exported(store, tmp_path_factory):
    db, _ = store
    before = digest(db)
    out = tmp_path_factory.mktemp("exported") / "out"
    r = run("export_survey", "--db", db, "--out", out, "--origin", ",".join(map(str, ORIGIN)))
    assert r.returncode == 0, r.stderr
    assert digest(db) == before  # read-only
    return out, r


def store_rows(db, sql):
    con = sqlite3.connect("file:%s?mode=ro" % db, uri=True)
    try:
        return con.execute(sql).fetchall()
    finally:
        con.close()


def read_tum(path):
    out = []
    for line in path.read_text().splitlines():
        v = [float(t) for t in line.split()]
        assert len(v) == 8 and v[3] == 0.0 and v[4] == 0.0 and v[5] == 0.0
        out.append((v[0], v[1], v[2], 2.0 * math.atan2(v[6], v[7])))
    return out


def aligned_rmse(est, gt):
    """Best rigid 2-D fit (Kabsch through an SVD, no scale) of est onto gt, then the RMSE."""
    est, gt = np.asarray(est, float), np.asarray(gt, float)
    ce, cg = est.mean(axis=0), gt.mean(axis=0)
    u, _, vt = np.linalg.svd((est - ce).T @ (gt - cg))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, d]) @ u.T
    res = (est - ce) @ r.T + cg - gt
    return float(np.sqrt(np.mean(np.sum(res * res, axis=1))))


def evaluate_metrics(survey, run_dir, report):
    import subprocess
    r = subprocess.run(["/usr/bin/python3", EVALUATE, "--run", str(run_dir), "--session", str(survey / "a"),
                        "--session", str(survey / "b"), "--world-gt", str(survey / "world_gt.csv"), "--report",
                        str(report), "--no-plots"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return json.loads((report / "metrics.json").read_text())


def truth_by_stamp(folder):
    stamp = {int(f["index"]): float(f["stamp_s"]) for f in rows(folder / "frames.csv")}
    return {round(stamp[int(g["index"])], 6): (float(g["x_m"]), float(g["y_m"])) for g in rows(folder / "gt.csv")}


def test_tum_tracks_score_like_evaluate(exported, store, survey, tmp_path):
    out, _ = exported
    metrics = evaluate_metrics(survey, store[1], tmp_path / "report")
    sessions = sorted(p for p in os.listdir(out) if p.startswith("session_") and p.endswith(".tum"))
    assert len(sessions) == 2
    for number, (name, folder) in enumerate(zip(sessions, ("a", "b"))):
        tum = read_tum(out / name)
        truth = truth_by_stamp(survey / folder)
        # z-up map frame -> the image axes gt.csv uses: (x, y) -> (x, -y) (doc/frames.md)
        est = [(x, -y) for _, x, y, _ in tum]
        gt = [truth[round(t, 6)] for t, _, _, _ in tum]
        mine = aligned_rmse(est, gt)
        theirs = metrics["session"][str(number)]["slam"]["ate_aligned_rmse_m"]
        assert len(tum) == metrics["session"][str(number)]["slam"]["n_keyframes"]
        assert abs(mine - theirs) < 1e-6, (name, mine, theirs)
    # the joined map: one TUM file holding both sessions, scored against world_gt.csv
    maps = sorted(p for p in os.listdir(out) if p.startswith("map_") and p.endswith(".tum"))
    assert len(maps) == 1
    sessions_in_store = sorted({int(c["session"]) for c in rows(out / maps[0].replace(".tum", ".csv"))})
    world = {}  # (store session, stamp) -> world gt; the two folders' stamps may coincide
    for number, folder in enumerate(("a", "b")):
        stamp = {int(f["index"]): float(f["stamp_s"]) for f in rows(survey / folder / "frames.csv")}
        for w in rows(survey / "world_gt.csv"):
            if int(w["session"]) == number:
                world[(sessions_in_store[number], round(stamp[int(w["index"])], 6))] = (float(w["x_m"]), float(w["y_m"]))
    tum = read_tum(out / maps[0])
    keys = [(int(c["session"]), round(float(c["stamp_s"]), 6)) for c in rows(out / maps[0].replace(".tum", ".csv"))]
    mine = aligned_rmse([(x, -y) for _, x, y, _ in tum], [world[k] for k in keys])
    theirs = metrics["map"]["0"]["slam"]["ate_aligned_rmse_m"]
    assert abs(mine - theirs) < 1e-6, (mine, theirs)


def test_kitti_and_csv_hold_the_same_poses(exported):
    out, _ = exported
    for tum_name in [p for p in os.listdir(out) if p.endswith(".tum")]:
        base = out / tum_name[:-4]
        tum = read_tum(out / tum_name)
        kitti = [[float(v) for v in line.split()] for line in (base.with_suffix(".kitti")).read_text().splitlines()]
        csv_rows = rows(base.with_suffix(".csv"))
        assert len(kitti) == len(tum) == len(csv_rows)
        for (t, x, y, yaw), k, c in zip(tum, kitti, csv_rows):
            assert len(k) == 12
            assert k[3] == pytest.approx(x, abs=1e-8) and k[7] == pytest.approx(y, abs=1e-8)
            assert math.atan2(k[4], k[0]) == pytest.approx(yaw, abs=1e-8)
            assert float(c["stamp_s"]) == pytest.approx(t, abs=1e-6)
            cov = np.array([[float(c["cov_xx"]), float(c["cov_xy"]), float(c["cov_xyaw"])],
                            [float(c["cov_xy"]), float(c["cov_yy"]), float(c["cov_yyaw"])],
                            [float(c["cov_xyaw"]), float(c["cov_yyaw"]), float(c["cov_yawyaw"])]])
            assert np.all(np.linalg.eigvalsh(cov) >= -1e-12)
        first = csv_rows[0]
        if tum_name.startswith("map_"):
            assert float(first["cov_xx"]) == 0.0  # the map's origin is exact
        # the covariance grows along the track (composed motions)
        assert float(csv_rows[-1]["cov_xx"]) + float(csv_rows[-1]["cov_yy"]) > \
            float(csv_rows[1]["cov_xx"]) + float(csv_rows[1]["cov_yy"])


def parse_g2o(path):
    vertices, edges, fixed = {}, [], []
    for line in path.read_text().splitlines():
        t = line.split()
        if t[0] == "VERTEX_SE2":
            vertices[int(t[1])] = tuple(map(float, t[2:5]))
        elif t[0] == "EDGE_SE2":
            v = list(map(float, t[3:]))
            info = np.array([[v[3], v[4], v[5]], [v[4], v[6], v[7]], [v[5], v[7], v[8]]])
            edges.append((int(t[1]), int(t[2]), tuple(v[:3]), info))
        elif t[0] == "FIX":
            fixed.append(int(t[1]))
        else:
            raise AssertionError("unknown g2o line " + line)
    return vertices, edges, fixed


def flipped(x, y, yaw, cov_blob):
    """A stored (image axes) measurement in the z-up frame, with its information matrix."""
    c = np.array(struct.unpack("9d", cov_blob)).reshape(3, 3)
    f = np.diag([1.0, -1.0, -1.0])
    return (x, -y, -yaw), np.linalg.inv(f @ c @ f)


def test_g2o_round_trips_the_store_graph(exported, store):
    out, _ = exported
    db, _ = store
    sessions = [s for (s,) in store_rows(db, "SELECT id FROM sessions ORDER BY id")]
    loops = store_rows(db, "SELECT session_a, keyframe_a, session_b, keyframe_b, x, y, yaw, cov FROM loops "
                           "WHERE refused = 0 AND summarised = 0")
    for s in sessions:
        vertices, edges, fixed = parse_g2o(out / ("session_%d.g2o" % s))
        tum = read_tum(out / ("session_%d.tum" % s))
        assert fixed == [0] and sorted(vertices) == list(range(len(tum)))
        for i, (_, x, y, yaw) in enumerate(tum):
            assert vertices[i] == pytest.approx((x, y, yaw), abs=1e-8)
        expected = {}
        for k, x, y, yaw, cov in store_rows(db, "SELECT keyframe, x, y, yaw, cov FROM motions WHERE session = %d" % s):
            expected[(k - 1, k)] = flipped(x, y, yaw, cov)
        for sa, ka, sb, kb, x, y, yaw, cov in loops:
            if sa == s and sb == s:
                expected[(ka, kb)] = flipped(x, y, yaw, cov)
        assert len(edges) == len(expected) and len(expected) > len(tum) - 1  # loops included
        for a, b, z, info in edges:
            z_ref, info_ref = expected[(a, b)]
            assert z == pytest.approx(z_ref, abs=1e-9)
            assert np.allclose(info, info_ref, rtol=1e-9, atol=1e-9)
    # the map: both sessions, the link between them
    (map_file,) = [p for p in os.listdir(out) if p.startswith("map_") and p.endswith(".g2o")]
    vertices, edges, _ = parse_g2o(out / map_file)
    n = [len(read_tum(out / ("session_%d.tum" % s))) for s in sessions]
    assert len(vertices) == sum(n)
    (link,) = store_rows(db, "SELECT x, y, yaw, cov FROM links")
    z_ref, info_ref = flipped(*link)
    joined = [e for e in edges if e[0] == n[0] - 1 and e[1] == n[0]]
    assert len(joined) == 1 and joined[0][2] == pytest.approx(z_ref, abs=1e-9)
    assert np.allclose(joined[0][3], info_ref, rtol=1e-9)


def meridian_and_normal_radii(lat_deg):
    a, f = 6378137.0, 1 / 298.257223563
    e2 = f * (2 - f)
    s = math.sin(math.radians(lat_deg))
    w = math.sqrt(1 - e2 * s * s)
    return a * (1 - e2) / w ** 3, a / w


def test_geojson_tracks_are_the_map_tracks_in_wgs84(exported):
    out, _ = exported
    lat0, lon0, heading = ORIGIN
    m, n = meridian_and_normal_radii(lat0)
    h = math.radians(heading)
    for name in [p for p in os.listdir(out) if p.endswith(".geojson")]:
        data = json.loads((out / name).read_text())
        assert data["type"] == "FeatureCollection"
        tum = read_tum(out / name.replace(".geojson", ".tum"))
        coords = [c for f in data["features"] for c in f["geometry"]["coordinates"]]
        assert len(coords) == len(tum)
        for (lon, lat), (_, x, y, _) in zip(coords, tum):
            north = math.radians(lat - lat0) * m
            east = math.radians(lon - lon0) * n * math.cos(math.radians(lat0))
            # x points at compass heading h, y 90 degrees anticlockwise of it
            assert east == pytest.approx(x * math.sin(h) - y * math.cos(h), abs=2e-3)
            assert north == pytest.approx(x * math.cos(h) + y * math.sin(h), abs=2e-3)


def test_help_lists_every_option():
    r = run("export_survey", "--help")
    assert r.returncode == 0
    for option in ("--db", "--out", "--origin", "--quiet", "--resolution", "--images", "--blend", "--no-exposure",
                   "--tile", "--no-mosaic", "--run", "--session"):
        assert option in r.stdout


def test_missing_store_is_a_clear_error(tmp_path):
    r = run("export_survey", "--db", tmp_path / "none.db", "--out", tmp_path / "out")
    assert r.returncode == 1 and "none.db" in r.stderr and "no such file" in r.stderr
    assert not (tmp_path / "none.db").exists() and not (tmp_path / "out").exists()


def test_corrupt_store_is_left_byte_identical(store, tmp_path):
    db, _ = store
    bad = tmp_path / "bad.db"
    data = bytearray(db.read_bytes())
    page = 4096
    for i in range(page * 2, min(len(data), page * 6)):
        data[i] = (i * 7) & 0xFF
    bad.write_bytes(bytes(data))
    before = digest(bad)
    r = run("export_survey", "--db", bad, "--out", tmp_path / "out")
    assert r.returncode == 1 and "bad.db" in r.stderr and "corrupt" in r.stderr, r.stderr
    assert digest(bad) == before and not (tmp_path / "out").exists()
    assert sorted(os.listdir(tmp_path)) == ["bad.db"]  # no -wal, -shm or .lock beside it


def test_damaged_map_motions_are_refused_and_a_run_repairs_them(store, tmp_path):
    """A NaN among a map's stored (optimised) motions: the export refuses (it would draw the map
    unoptimised or NaN) and names the fix; offline_slam --db on the store rebuilds the map from its
    sessions' odometry, links and loops, optimises it and saves it: then the export goes through."""
    db, _ = store
    bad = tmp_path / "bad.db"
    bad.write_bytes(db.read_bytes())
    con = sqlite3.connect(str(bad))
    map_id, blob = con.execute("SELECT id, motions FROM maps ORDER BY id LIMIT 1").fetchone()
    blob = bytearray(blob)
    blob[8:16] = struct.pack("<d", float("nan"))
    con.execute("UPDATE maps SET motions = ? WHERE id = ?", (bytes(blob), map_id))
    con.commit()
    con.close()
    r = run("export_survey", "--db", bad, "--out", tmp_path / "out")
    assert r.returncode == 1 and "stored motion 0 is damaged (mean not finite)" in r.stderr, r.stderr
    assert "offline_slam --db on the store saves it repaired" in r.stderr and not (tmp_path / "out").exists()
    r = run("offline_slam", "--db", bad, "--detect-loops", "--out", tmp_path / "run")
    assert r.returncode == 0, r.stderr
    assert "stored motion 0 is damaged" in r.stdout + r.stderr
    assert all(math.isfinite(float(t["x_m"])) for t in rows(tmp_path / "run" / "trajectory.csv"))
    r = run("export_survey", "--db", bad, "--out", tmp_path / "out")
    assert r.returncode == 0, r.stderr


def test_not_a_store_and_empty_file(tmp_path):
    (tmp_path / "text.db").write_text("hello")
    r = run("export_survey", "--db", tmp_path / "text.db", "--out", tmp_path / "out")
    assert r.returncode == 1 and "not an SQLite database" in r.stderr
    (tmp_path / "empty.db").write_bytes(b"")
    r = run("export_survey", "--db", tmp_path / "empty.db", "--out", tmp_path / "out")
    assert r.returncode == 1 and "empty" in r.stderr


def test_bad_images_folder_is_refused_before_any_output(store, tmp_path):
    db, _ = store
    r = run("export_survey", "--db", db, "--out", tmp_path / "out", "--images", tmp_path / "nowhere")
    assert r.returncode == 1 and "nowhere" in r.stderr, r.stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("option,value", [("--origin", v) for v in ("91,5,0", "43,181,0", "43,5", "a,b,c", "43,5,0,1",
                                                                      "43,5,nan")] +
                         [("--resolution", v) for v in ("0", "-0.01", "abc", "nan", "1e9", "")] +
                         [("--blend", "gaussian"), ("--tile", "10"), ("--tile", "100.5")])
def test_bad_option_values_are_refused(store, tmp_path, option, value):
    db, _ = store
    r = run("export_survey", "--db", db, "--out", tmp_path / "out", option, value)
    assert r.returncode == 2 and option in r.stderr, r.stderr
    assert not (tmp_path / "out").exists()


def test_a_keyframe_without_valid_altitude_is_left_out_of_the_mosaic(store, tmp_path):
    """A bad row (altitude -1, as a damaged store could hold) is counted as missing, not drawn at a
    NaN place; every file is still written."""
    db, _ = store
    bad = tmp_path / "bad_altitude.db"
    bad.write_bytes(db.read_bytes())
    con = sqlite3.connect(str(bad))
    first = con.execute("SELECT MIN(id) FROM sessions").fetchone()[0]
    con.execute("UPDATE keyframes SET altitude = -1 WHERE session = ? AND keyframe = 3", (first,))
    con.commit()
    con.close()
    r = run("export_survey", "--db", bad, "--out", tmp_path / "out")
    assert r.returncode == 0, r.stderr
    line = next(x for x in r.stdout.splitlines() if x.startswith("session_%d.png" % first))
    assert line.endswith(", 1 missing"), line
    assert len([p for p in os.listdir(tmp_path / "out") if p.endswith(".png")]) == 3


def test_missing_arguments(tmp_path):
    assert run("export_survey", "--out", tmp_path).returncode == 2
    assert run("export_survey", "--db", tmp_path / "x.db").returncode == 2
    r = run("export_survey", "--db")
    assert r.returncode == 2 and "needs a value" in r.stderr


# --- export_survey --run: from an offline_slam output folder and its dataset folders

@pytest.fixture(scope="module")
def exported_run(store, survey, tmp_path_factory):
    _, run_dir = store
    out = tmp_path_factory.mktemp("exported_run") / "out"
    r = run("export_survey", "--run", run_dir, "--session", survey / "a", survey / "b", "--out", out, "--origin",
            ",".join(map(str, ORIGIN)))
    assert r.returncode == 0, r.stderr
    return out, r


def test_run_folder_export_gives_the_stores_tum_poses(exported, exported_run):
    from_store, _ = exported
    from_run, r = exported_run
    def tum_files(folder):  # sessions by id, then the map (the same ids: a session's id is its store id)
        names = [p for p in os.listdir(folder) if p.endswith(".tum")]
        return sorted(names, key=lambda p: (p.startswith("map_"), int(p.split("_")[1].split(".")[0])))

    tums = list(zip(tum_files(from_store), tum_files(from_run)))
    assert len(tums) == 3  # two sessions and their map
    for name, theirs in tums:
        assert name.split("_")[0] == theirs.split("_")[0]
        a, b = read_tum(from_store / name), read_tum(from_run / theirs)
        assert len(a) == len(b) > 5, name
        for (ta, xa, ya, yaw_a), (tb, xb, yb, yaw_b) in zip(a, b):
            assert tb == pytest.approx(ta, abs=1e-6)
            # trajectory.csv prints 6 decimals (x, y) and 7 (yaw)
            assert abs(xa - xb) <= 6e-7 and abs(ya - yb) <= 6e-7, (name, xa, xb, ya, yb)
            assert abs(math.remainder(yaw_a - yaw_b, 2 * math.pi)) <= 1e-6, (name, yaw_a, yaw_b)
    for name, theirs in tums:  # the KITTI files hold the same poses
        ka = np.loadtxt(from_store / name.replace(".tum", ".kitti"))
        kb = np.loadtxt(from_run / theirs.replace(".tum", ".kitti"))
        assert np.abs(ka - kb).max() < 2e-6
    assert "note: from an offline_slam output folder" in r.stdout


def test_run_folder_export_marks_what_the_folder_lacks(exported, exported_run):
    from_store, _ = exported
    from_run, _ = exported_run
    def renumbered(name):  # the store's name of a run file: the same (a session's id is its store id,
        return name         # and a store numbers from 0 as the engine; stores numbered from 1 before)

    for name in (p for p in os.listdir(from_run) if p.endswith(".csv")):
        store_rows, run_rows = rows(from_store / renumbered(name)), rows(from_run / name)
        assert [r["frame_index"] for r in run_rows] == [r["frame_index"] for r in store_rows]
        assert [int(r["session"]) for r in run_rows] == [int(r["session"]) for r in store_rows]
        for r in run_rows:  # no covariance in the folder: unknown, not invented
            assert [r[c] for c in ("cov_xx", "cov_xy", "cov_xyaw", "cov_yy", "cov_yyaw", "cov_yawyaw")] == ["nan"] * 6
    g2o = sorted(p for p in os.listdir(from_run) if p.endswith(".g2o"))
    assert sorted(map(renumbered, g2o)) == sorted(p for p in os.listdir(from_store) if p.endswith(".g2o"))
    for name in g2o:
        lines = (from_run / name).read_text().splitlines()
        stored = (from_store / renumbered(name)).read_text().splitlines()
        assert sum(v.startswith("VERTEX_SE2") for v in lines) == sum(v.startswith("VERTEX_SE2") for v in stored)
        unknown = [v for v in lines if v.startswith("# EDGE_SE2") and v.endswith(")")]
        edges = [v.split() for v in lines if v.startswith("EDGE_SE2")]
        assert all("information unknown" in v for v in unknown)
        # every odometry motion (and link) is there, without information; the loops with theirs
        n_vertices = sum(v.startswith("VERTEX_SE2") for v in lines)
        assert len(unknown) == n_vertices - 1, name
        for e in edges:
            info = [float(v) for v in e[6:]]
            assert len(info) == 6 and all(math.isfinite(v) for v in info) and info[0] > 0
    maps = [p for p in g2o if p.startswith("map_")]
    assert any(v.startswith("EDGE_SE2") for v in (from_run / maps[0]).read_text().splitlines())  # loops
    names = os.listdir(from_run)
    for ext in (".geojson", ".png", ".pgw", ".tif"):
        assert len([p for p in names if p.endswith(ext)]) == 3, ext


def test_run_folder_mosaics_are_drawn_from_the_folders_frames(exported_run):
    _, r = exported_run
    drawn = [line for line in r.stdout.splitlines() if ".png: " in line]
    assert len(drawn) == 3
    for line in drawn:
        frames = int(line.split("images: ")[1].split(" frames")[0])
        assert frames > 5 and " 0 thumbnails, 0 missing" in line, line


def test_run_folder_with_other_dataset_folders_is_refused(store, survey, tmp_path):
    _, run_dir = store
    r = run("export_survey", "--run", run_dir, "--session", survey / "b", survey / "a", "--out", tmp_path / "out")
    assert r.returncode == 1 and "not the same folder" in r.stderr, r.stderr
    assert not (tmp_path / "out").exists()
    r = run("export_survey", "--run", tmp_path / "nowhere", "--out", tmp_path / "out")
    assert r.returncode == 1 and "nowhere" in r.stderr
    r = run("export_survey", "--run", run_dir, "--db", tmp_path / "x.db", "--out", tmp_path / "out")
    assert r.returncode == 2
    r = run("export_survey", "--run", run_dir, "--images", survey / "a", "--out", tmp_path / "out")
    assert r.returncode == 2 and "--images" in r.stderr


def test_map_covariances_are_the_stored_motions_composed(exported, store):
    """First-order composition (Smith, Self and Cheeseman) of the map's stored optimised motions,
    done here in numpy, gives every row's covariance in the map's CSV (z-up: F P F)."""
    out, _ = exported
    db, _ = store
    (map_id, blob), = store_rows(db, "SELECT id, motions FROM maps WHERE motions IS NOT NULL")
    motions = np.frombuffer(blob, dtype="<f8").reshape(-1, 12)
    csv_rows = rows(out / ("map_%d.csv" % map_id))
    assert len(csv_rows) == len(motions) + 1
    pose, cov = np.zeros(3), np.zeros((3, 3))
    f = np.diag([1.0, -1.0, -1.0])
    for row, m in zip(csv_rows[1:], motions):
        c, s = math.cos(pose[2]), math.sin(pose[2])
        j1 = np.array([[1, 0, -s * m[0] - c * m[1]], [0, 1, c * m[0] - s * m[1]], [0, 0, 1]])
        j2 = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        cov = j1 @ cov @ j1.T + j2 @ m[3:].reshape(3, 3) @ j2.T
        pose = np.array([pose[0] + c * m[0] - s * m[1], pose[1] + s * m[0] + c * m[1], pose[2] + m[2]])
        mine = f @ cov @ f
        got = np.array([[float(row["cov_xx"]), float(row["cov_xy"]), float(row["cov_xyaw"])],
                        [float(row["cov_xy"]), float(row["cov_yy"]), float(row["cov_yyaw"])],
                        [float(row["cov_xyaw"]), float(row["cov_yyaw"]), float(row["cov_yawyaw"])]])
        assert np.allclose(got, mine, rtol=1e-7, atol=1e-15), (row, mine)
        assert float(row["x_m"]) == pytest.approx(pose[0], abs=1e-8)
        assert float(row["y_m"]) == pytest.approx(-pose[1], abs=1e-8)


# --- mosaics ------------------------------------------------------------------------------------

def read_raster(path):
    """(rows, cols, bands) uint8 array and the GDAL dataset's geotransform and projection."""
    from osgeo import gdal
    ds = gdal.Open(str(path))
    assert ds is not None, path
    data = np.dstack([ds.GetRasterBand(b + 1).ReadAsArray() for b in range(ds.RasterCount)])
    return data, ds.GetGeoTransform(), ds.GetProjection()


def read_world_file(path):
    a, d, b, e, c, f = (float(v) for v in path.read_text().split())
    return a, d, b, e, c, f


def read_camera(folder):
    cam = {}
    for line in (folder / "camera.yaml").read_text().splitlines():
        if ":" in line:
            k, v = line.split(":", 1)
            cam[k.strip()] = v.strip()
    return {k: float(cam[k]) for k in ("fx", "fy", "cx", "cy")}


def gray(rgb):
    return rgb[..., :3].astype(float) @ np.array([0.299, 0.587, 0.114])


def ncc(a, b):
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / math.sqrt((a * a).sum() * (b * b).sum()))


def expected_patch(keyframe, camera, image, world, centre_px, half):
    """The source image sampled (nearest) at the mosaic pixels around centre_px, by the test's own
    geometry: world file -> z-up map point -> image axes -> camera pixel at the keyframe's pose."""
    a, _, _, e, c, f = world
    cols = np.arange(centre_px[0] - half, centre_px[0] + half)
    rows_ = np.arange(centre_px[1] - half, centre_px[1] + half)
    cc, rr = np.meshgrid(cols, rows_)
    x, y = c + cc * a, f + rr * e                       # z-up map frame
    X, Y = x, -y                                        # image axes
    tx, ty, psi = float(keyframe["x_m"]), -float(keyframe["y_m"]), -float(keyframe["yaw_rad"])
    dx, dy = X - tx, Y - ty
    u = camera["cx"] + (math.cos(psi) * dx + math.sin(psi) * dy) * camera["fx"] / float(keyframe["altitude_m"])
    v = camera["cy"] + (-math.sin(psi) * dx + math.cos(psi) * dy) * camera["fy"] / float(keyframe["altitude_m"])
    ui, vi = np.rint(u).astype(int), np.rint(v).astype(int)
    assert ui.min() >= 0 and vi.min() >= 0 and ui.max() < image.shape[1] and vi.max() < image.shape[0]
    return gray(image[vi, ui])


def test_a_folder_of_another_cameras_images_is_not_drawn(store, survey, tmp_path):
    """--images matches frames by stamp and index, which another mission shares (simulated ones
    do): a folder whose camera.yaml gives another image size is left out, said so, and the
    session's own stored thumbnails are drawn instead of the other camera's frames."""
    db, _ = store
    foreign = tmp_path / "foreign"
    shutil.copytree(survey / "a", foreign)
    cam = (foreign / "camera.yaml").read_text()
    width = int(re.search(r"image_width: *(\d+)", cam).group(1))
    height = int(re.search(r"image_height: *(\d+)", cam).group(1))
    cam = re.sub(r"image_width: *\d+", "image_width: %d" % (2 * width), cam)
    (foreign / "camera.yaml").write_text(re.sub(r"image_height: *\d+", "image_height: %d" % (2 * height), cam))
    r = run("export_survey", "--db", db, "--out", tmp_path / "out", "--images", foreign)
    assert r.returncode == 0, r.stderr
    matched = [line for line in r.stdout.splitlines() if line.startswith("images of session_")]
    assert len(matched) == 2, r.stdout
    for line in matched:
        assert "no folder holds its keyframes (thumbnails drawn)" in line, line
        assert "1 folder(s) of images other than its camera's %dx%d left out" % (width, height) in line, line
    assert "0 missing" in r.stdout and ", 0 thumbnails" not in r.stdout, r.stdout


@pytest.mark.parametrize("resolution, size", [("1e-300", r"\d\.\d+e\+30\d x \d\.\d+e\+30\d"),
                                              ("1e-05", r"\d{6,7} x \d{6,7}")])
def test_a_mosaic_too_large_is_refused_with_its_size(store, tmp_path, resolution, size):
    """Too fine a --resolution: refused before anything is allocated, with the size it would have
    had (it printed -9223372036854775808 x -9223372036854775808 px when past any integer)."""
    db, _ = store
    r = run("export_survey", "--db", db, "--out", tmp_path / "out", "--resolution", resolution)
    assert r.returncode == 1, r.stdout
    assert re.search(size + " px at %s m/px is more than 1000 megapixels: give a coarser --resolution"
                     % resolution, r.stderr), r.stderr
    assert ": -" not in r.stderr and "x -" not in r.stderr, r.stderr


def test_a_session_stored_without_its_camera_still_finds_its_folder(store, survey, tmp_path):
    """Stores written before the fix keep a 0x0 camera for a session whose keyframe 0 never
    arrived: that camera is unknown, not "another size", so the session's own folder is drawn."""
    db, _ = store
    old = tmp_path / "old.db"
    shutil.copy(db, old)
    con = sqlite3.connect(str(old))
    con.execute("UPDATE sessions SET cam_width = 0, cam_height = 0")
    con.commit()
    con.close()
    r = run("export_survey", "--db", old, "--out", tmp_path / "out", "--images", survey / "a", survey / "b")
    assert r.returncode == 0, r.stderr
    matched = [line for line in r.stdout.splitlines() if line.startswith("images of session_")]
    assert len(matched) == 2, r.stdout
    for line in matched:
        assert "no folder holds" not in line and "left out" not in line, line
        assert re.search(r", (\d+) of \1 keyframes", line), line


def test_a_session_stored_without_a_camera_is_exported_without_its_mosaic(store, tmp_path):
    """A session stored with a 0x0 camera (older stores, keyframe 0 lost): its track files are
    written and its mosaic left out with the reason; the map's mosaic is drawn from the other
    session (it failed the whole export with 'no keyframe ... has a valid pose and altitude')."""
    db, _ = store
    old = tmp_path / "old.db"
    shutil.copy(db, old)
    con = sqlite3.connect(str(old))
    (first,) = con.execute("SELECT min(id) FROM sessions").fetchone()
    con.execute("UPDATE sessions SET cam_width = 0, cam_height = 0, cam_fx = 0, cam_fy = 0, cam_cx = 0, cam_cy = 0 "
                "WHERE id = ?", (first,))
    con.commit()
    con.close()
    out = tmp_path / "out"
    r = run("export_survey", "--db", old, "--out", out)
    assert r.returncode == 0, r.stderr
    label = "session_%d" % first
    assert "%s.png: not drawn: no session of %s has a stored camera" % (label, label) in r.stdout, r.stdout
    assert not (out / (label + ".png")).exists()
    for ext in (".tum", ".kitti", ".csv", ".g2o"):
        assert (out / (label + ext)).stat().st_size > 0
    other = [p.name for p in out.glob("session_*.png")]
    assert len(other) == 1 and other[0] != label + ".png", other
    (map_png,) = [line for line in r.stdout.splitlines() if line.startswith("map_") and ".png:" in line]
    n_other, n_first = len(rows(out / other[0].replace(".png", ".csv"))), len(rows(out / (label + ".csv")))
    # The other session's keyframes drawn from their thumbnails, the first's counted missing.
    assert "images: 0 frames, %d thumbnails, %d missing" % (n_other, n_first) in map_png, (map_png, n_other, n_first)


@pytest.fixture(scope="module")
def full_mosaics(store, survey, tmp_path_factory):
    db, _ = store
    out = tmp_path_factory.mktemp("mosaics") / "out"
    r = run("export_survey", "--db", db, "--out", out, "--images", survey / "a", survey / "b", "--resolution", "0.01")
    assert r.returncode == 0, r.stderr
    return out, r


def test_mosaic_puts_each_keyframe_image_at_its_pose(full_mosaics, survey):
    out, r = full_mosaics
    assert "0 thumbnails, 0 missing" in r.stdout, r.stdout
    # both folders hold frames with the same indexes and stamps: each session gets its own
    matched = [line for line in r.stdout.splitlines() if line.startswith("images of session_")]
    assert len(matched) == 2 and "ambiguous" not in r.stdout
    for line, folder in zip(matched, ("a", "b")):
        assert line.endswith("%s, %s keyframes" % (survey / folder, line.split(", ")[-1].split(" keyframes")[0]))
    sessions = sorted(int(p[8:-4]) for p in os.listdir(out) if p.startswith("session_") and p.endswith(".csv"))
    checked = 0
    for s, folder in zip(sessions, ("a", "b")):
        for prefix in ("session_%d" % s, [p[:-4] for p in os.listdir(out) if p.startswith("map_")
                                           and p.endswith(".png")][0]):
            mosaic, _, _ = read_raster(out / (prefix + ".png"))
            world = read_world_file(out / (prefix + ".pgw"))
            assert world[0] == pytest.approx(0.01) and world[3] == pytest.approx(-0.01) and world[1] == world[2] == 0
            rows_csv = [k for k in rows(out / (prefix + ".csv")) if int(k["session"]) == s]
            frames = {int(f["index"]): f["image"] for f in rows(survey / folder / "frames.csv")}
            camera = read_camera(survey / folder)
            for k in (rows_csv[len(rows_csv) // 3], rows_csv[2 * len(rows_csv) // 3]):
                image, _, _ = read_raster(survey / folder / frames[int(k["frame_index"])])
                centre = (int(round((float(k["x_m"]) - world[4]) / world[0])),
                          int(round((float(k["y_m"]) - world[5]) / world[3])))
                half = 40
                assert mosaic[centre[1] - half:centre[1] + half, centre[0] - half:centre[0] + half, 3].min() == 255
                expected = expected_patch(k, camera, image, world, centre, half)
                # The blend averages overlapping frames (noise, marine snow, light differ), so the
                # registration is judged by where the correlation peaks: at the pose, to a pixel.
                scores = {(dx, dy): ncc(gray(mosaic[centre[1] - half + dy:centre[1] + half + dy,
                                                    centre[0] - half + dx:centre[0] + half + dx]), expected)
                          for dx in range(-4, 5) for dy in range(-4, 5)}
                peak = max(scores, key=scores.get)
                assert abs(peak[0]) <= 1 and abs(peak[1]) <= 1, (prefix, k["keyframe"], peak, scores[peak])
                assert scores[peak] > 0.8, (prefix, k["keyframe"], scores[peak])
                assert scores[(4, 4)] < scores[peak] - 0.2
                checked += 1
    assert checked == 8


def test_unblended_mosaic_shows_the_last_keyframe_as_it_is(store, survey, tmp_path):
    """--blend none draws the keyframes in order, each over the earlier ones: around its centre the
    last keyframe of a session is its own image, placed by the world file."""
    db, _ = store
    out = tmp_path / "out"
    r = run("export_survey", "--db", db, "--out", out, "--images", survey / "a", survey / "b", "--resolution", "0.01",
            "--blend", "none", "--no-exposure")
    assert r.returncode == 0, r.stderr
    sessions = sorted(int(p[8:-4]) for p in os.listdir(out) if p.startswith("session_") and p.endswith(".csv"))
    for s, folder in zip(sessions, ("a", "b")):
        mosaic, _, _ = read_raster(out / ("session_%d.png" % s))
        world = read_world_file(out / ("session_%d.pgw" % s))
        k = rows(out / ("session_%d.csv" % s))[-1]
        frames = {int(f["index"]): f["image"] for f in rows(survey / folder / "frames.csv")}
        image, _, _ = read_raster(survey / folder / frames[int(k["frame_index"])])
        centre = (int(round((float(k["x_m"]) - world[4]) / world[0])),
                  int(round((float(k["y_m"]) - world[5]) / world[3])))
        patch = mosaic[centre[1] - 40:centre[1] + 40, centre[0] - 40:centre[0] + 40]
        score = ncc(gray(patch), expected_patch(k, read_camera(survey / folder), image, world, centre, 40))
        assert score > 0.95, (s, score)


def test_mosaic_outputs_and_transparency(exported):
    out, r = exported
    assert "thumbnails" in r.stdout  # no --images: says what was drawn
    for png in [p for p in os.listdir(out) if p.endswith(".png")]:
        data, _, _ = read_raster(out / png)
        assert data.shape[2] == 4
        alpha = data[..., 3]
        assert 0.2 < (alpha == 255).mean() < 1.0  # covered and uncovered pixels
        assert (data[..., :3][alpha == 0] == 0).all()
        assert (out / png.replace(".png", ".pgw")).exists()
    assert not [p for p in os.listdir(out) if ".tmp" in p]  # nothing half-written left behind


def test_geotiff_carries_the_origin(exported):
    out, _ = exported
    lat0, lon0, heading = ORIGIN
    h = math.radians(heading)
    tifs = [p for p in os.listdir(out) if p.endswith(".tif")]
    assert len(tifs) == 3  # two sessions, one map
    for tif in tifs:
        data, gt, wkt = read_raster(out / tif)
        png, _, _ = read_raster(out / tif.replace(".tif", ".png"))
        assert np.array_equal(data, png)
        a, _, _, e, c, f = read_world_file(out / tif.replace(".tif", ".pgw"))
        x0, y0 = c - a / 2, f - e / 2  # the upper-left corner in the z-up map frame
        east0 = x0 * math.sin(h) - y0 * math.cos(h)
        north0 = x0 * math.cos(h) + y0 * math.sin(h)
        assert gt == pytest.approx((east0, a * math.sin(h), a * math.cos(h), north0, a * math.cos(h), -a * math.sin(h)),
                                   abs=1e-9)
        assert "Transverse_Mercator" in wkt and "WGS" in wkt
        assert '"latitude_of_origin",%s' % lat0 in wkt.replace(" ", "") and \
            '"central_meridian",%s' % lon0 in wkt.replace(" ", "")


def test_no_geotiff_without_origin(store, tmp_path):
    db, _ = store
    r = run("export_survey", "--db", db, "--out", tmp_path / "out", "--blend", "feather", "--no-exposure")
    assert r.returncode == 0, r.stderr
    names = os.listdir(tmp_path / "out")
    assert not [p for p in names if p.endswith(".tif") or p.endswith(".geojson")]
    assert len([p for p in names if p.endswith(".png")]) == 3


# --- evaluate.py --mosaic-score ----------------------------------------------------------

def mosaic_scores(survey, run_dir, report):
    import subprocess
    r = subprocess.run(["/usr/bin/python3", EVALUATE, "--run", str(run_dir), "--session", str(survey / "a"),
                        "--session", str(survey / "b"), "--world-gt", str(survey / "world_gt.csv"), "--report",
                        str(report), "--no-plots", "--mosaic-score"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "## Mosaic consistency (slam)" in r.stdout
    return json.loads((report / "metrics.json").read_text())["map"]["0"]["slam"]


def test_mosaic_score_of_the_map_is_close_to_the_ground_truths(store, survey, tmp_path):
    _, run_dir = store
    m = mosaic_scores(survey, run_dir, tmp_path / "report")
    assert m["mosaic_pairs"] > 20
    # z-scored unrelated images differ by 2/sqrt(pi) = 1.13 on average: the ground truth's
    # overlaps agree far better (what is left is the frames' own noise, light and haze)
    assert m["mosaic_disagreement_gt"] < 0.8
    assert abs(m["mosaic_ratio"] - 1.0) < 0.1, m
    # a map with session b turned by 3 degrees about its first keyframe scores clearly worse
    bad = tmp_path / "bad_run"
    bad.mkdir()
    for name in os.listdir(run_dir):
        (bad / name).write_bytes((run_dir / name).read_bytes())
    lines = (run_dir / "trajectory.csv").read_text().splitlines()
    header, body = lines[0], [line.split(",") for line in lines[1:]]
    first_b = next(r for r in body if r[0] == "1")
    x0, y0, t = float(first_b[3]), float(first_b[4]), math.radians(3.0)
    for r in body:
        if r[0] == "1":
            dx, dy = float(r[3]) - x0, float(r[4]) - y0
            r[3] = "%.6f" % (x0 + math.cos(t) * dx - math.sin(t) * dy)
            r[4] = "%.6f" % (y0 + math.sin(t) * dx + math.cos(t) * dy)
            r[5] = "%.7f" % (float(r[5]) + t)
    (bad / "trajectory.csv").write_text("\n".join([header] + [",".join(r) for r in body]) + "\n")
    worse = mosaic_scores(survey, bad, tmp_path / "bad_report")
    assert worse["mosaic_disagreement_gt"] == pytest.approx(m["mosaic_disagreement_gt"], rel=1e-9)
    assert worse["mosaic_ratio"] > m["mosaic_ratio"] + 0.1, (worse, m)


# --- keyframe images in the store --------------------------------------------------------

# IJG's luminance quantisation table (JPEG Annex K.1), natural order, and libjpeg's scaling by quality
IJG_LUMA = [16, 11, 10, 16, 24, 40, 51, 61, 12, 12, 14, 19, 26, 58, 60, 55, 14, 13, 16, 24, 40, 57, 69, 56,
            14, 17, 22, 29, 51, 87, 80, 62, 18, 22, 37, 56, 68, 109, 103, 77, 24, 35, 55, 64, 81, 104, 113, 92,
            49, 64, 78, 87, 103, 121, 120, 101, 72, 92, 95, 98, 112, 100, 103, 99]


def ijg_luma_table(quality):
    scale = 5000 // quality if quality < 50 else 200 - 2 * quality
    return [min(255, max(1, (q * scale + 50) // 100)) for q in IJG_LUMA]


def jpeg_header(blob):
    """(width, height, components, first quantisation table) read from the JPEG's markers."""
    assert blob[:2] == b"\xff\xd8", "not a JPEG"
    i, size, table = 2, None, None
    while i + 4 <= len(blob) and (size is None or table is None):
        assert blob[i] == 0xFF, i
        marker, length = blob[i + 1], struct.unpack(">H", blob[i + 2:i + 4])[0]
        if marker == 0xDB and table is None:  # DQT: Pq/Tq byte, then 64 8-bit values (zigzag order)
            assert blob[i + 4] >> 4 == 0
            table = list(blob[i + 5:i + 69])
        elif marker in (0xC0, 0xC1, 0xC2):  # SOF: precision, height, width, components
            h, w = struct.unpack(">HH", blob[i + 5:i + 9])
            size = (w, h, blob[i + 9])
        i += 2 + length
    return size + (table,)


def stored_images(db):
    return [bytes(b) for (b,) in store_rows(db, "SELECT thumbnail FROM keyframes ORDER BY session, keyframe")]


@pytest.fixture(scope="module")
def stores_by_image(survey, tmp_path_factory):
    """Stores written by offline_slam --db with the old 96 px thumbnail and a non-default 240 px, quality 85."""
    out = {}
    for side, quality in ((96, 70), (240, 85)):
        base = tmp_path_factory.mktemp("store_%d" % side)
        (base / "slam.yaml").write_text("store: {image_max_side_px: %d, image_jpeg_quality: %d}\n" % (side, quality))
        r = run("offline_slam", "--config", base / "slam.yaml", "--session", survey / "a", "--session", survey / "b",
                "--out", base / "run", "--db", base / "survey.db", "--quiet")
        assert r.returncode == 0, r.stderr
        out[side] = base / "survey.db"
    return out


def test_offline_slam_keeps_keyframe_images_of_the_configured_size_and_quality(store, stores_by_image):
    # the frames are 320 x 240: the default (320, quality 75) keeps them whole
    for db, size, quality in ((store[0], (320, 240), 75), (stores_by_image[240], (240, 180), 85),
                              (stores_by_image[96], (96, 72), 70)):
        images = stored_images(db)
        assert len(images) >= 15
        for blob in images:
            w, h, components, table = jpeg_header(blob)
            assert (w, h) == size and components == 1, (db, w, h, components)
            assert sorted(table) == sorted(ijg_luma_table(quality)), (db, quality, table)
    # a larger image costs more bytes, as bench_store measures
    mean = {side: np.mean([len(b) for b in stored_images(db)]) for side, db in stores_by_image.items()}
    assert mean[240] > 2 * mean[96], mean


def mosaic_line(stdout, prefix):
    line = next(x for x in stdout.splitlines() if x.startswith(prefix) and ".png:" in x)
    return line, float(line.split(" at ")[1].split(" m/px")[0])


def covered_grey(path):
    data, _, _ = read_raster(path)
    return gray(data), data[..., 3] == 255


def test_store_only_mosaics_are_finer_and_sharper_with_larger_images(stores_by_image, survey, tmp_path):
    """From the store alone (no --images) the automatic resolution is the stored image's ground pixel,
    and at a common resolution a 240 px image's mosaic is closer to the full-resolution frames'
    mosaic (correlation) and keeps more of its detail (gradient energy) than a 96 px thumbnail's."""
    results = {}
    for side, db in stores_by_image.items():
        r = run("export_survey", "--db", db, "--out", tmp_path / ("auto_%d" % side))
        assert r.returncode == 0, r.stderr
        line, res = mosaic_line(r.stdout, "map_")
        assert "0 frames" in line and "0 missing" in line, line  # the stored images only
        common = "--resolution", "0.007"
        r = run("export_survey", "--db", db, "--out", tmp_path / ("store_%d" % side), *common)
        assert r.returncode == 0, r.stderr
        r = run("export_survey", "--db", db, "--out", tmp_path / ("full_%d" % side), "--images", survey / "a",
                survey / "b", *common)
        assert r.returncode == 0, r.stderr
        name = [p for p in os.listdir(tmp_path / ("store_%d" % side)) if p.startswith("map_") and p.endswith(".png")][0]
        small, covered = covered_grey(tmp_path / ("store_%d" % side) / name)
        full, covered_full = covered_grey(tmp_path / ("full_%d" % side) / name)
        assert small.shape == full.shape
        both = covered & covered_full
        assert both.mean() > 0.5
        gy, gx = np.gradient(small)
        fy, fx = np.gradient(full)
        results[side] = dict(res=res, ncc=ncc(small[both], full[both]),
                             energy=float(np.hypot(gx, gy)[both].mean() / np.hypot(fx, fy)[both].mean()))
    print(results)
    # automatic resolution: the camera's ground pixel (2 m / 300 px at 320 px) times 320 / stored width
    assert results[240]["res"] == pytest.approx(results[96]["res"] * 96 / 240, rel=0.05), results
    # measured: 96 px NCC 0.947, gradient energy 0.35 of the full frames'; 240 px 0.993, 0.81
    assert 1.0 - results[240]["ncc"] < (1.0 - results[96]["ncc"]) / 3, results
    assert results[240]["energy"] > results[96]["energy"] + 0.3, results
    assert results[240]["ncc"] > 0.98, results


# --- evaluate.py --mosaic-png: the mosaics side by side ------------------------------------

def mosaic_pngs(survey, run_dir, directory):
    import subprocess
    from PIL import Image
    r = subprocess.run(["/usr/bin/python3", EVALUATE, "--run", str(run_dir), "--session", str(survey / "a"),
                        "--session", str(survey / "b"), "--world-gt", str(survey / "world_gt.csv"), "--report",
                        str(directory / "report"), "--no-plots", "--mosaic-png", str(directory / "png")],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "mosaic PNGs of map 0: " in r.stdout and "ratio " in r.stdout, r.stdout
    out = {}
    for name in ("slam", "gt"):
        path = directory / "png" / ("map_0_%s.png" % name)
        world = [float(v) for v in path.with_suffix(".pgw").read_text().split()]
        with Image.open(path) as im:
            assert im.mode == "RGBA"
            out[name] = (np.asarray(im, float), world)
    return out


def on_shared_window(a, b):
    """The two mosaics (RGBA array, world file) cut to the ground both rasters cover; the world files
    must share the resolution and a pixel grid."""
    (ia, wa), (ib, wb) = a, b
    assert wa[:4] == wb[:4]
    res = wa[0]
    dc, dr = (wb[4] - wa[4]) / res, (wa[5] - wb[5]) / res  # b's upper-left pixel in a's pixels
    assert abs(dc - round(dc)) < 1e-6 and abs(dr - round(dr)) < 1e-6, (dc, dr)
    dc, dr = int(round(dc)), int(round(dr))
    r0, c0 = max(0, dr), max(0, dc)
    r1, c1 = min(ia.shape[0], dr + ib.shape[0]), min(ia.shape[1], dc + ib.shape[1])
    assert r1 - r0 > 50 and c1 - c0 > 50
    return ia[r0:r1, c0:c1], ib[r0 - dr:r1 - dr, c0 - dc:c1 - dc]


def mean_colour_difference(a, b):
    both = (a[..., 3] > 0) & (b[..., 3] > 0)
    assert both.sum() > 10000
    return float(np.abs(a[both, :3] - b[both, :3]).mean())


def test_mosaic_pngs_of_estimate_and_ground_truth_side_by_side(store, survey, tmp_path):
    _, run_dir = store
    m = mosaic_pngs(survey, run_dir, tmp_path / "good")
    est, truth = m["slam"], m["gt"]
    assert est[0].shape == truth[0].shape and est[1] == truth[1]  # one extent, one resolution
    assert (truth[0][..., 3] > 0).mean() > 0.3
    close = mean_colour_difference(est[0], truth[0])  # a good map: its mosaic looks like the truth's
    # the whole map turned by 4 degrees about its origin (the first keyframe of session a)
    turned = tmp_path / "turned_run"
    turned.mkdir()
    for name in os.listdir(run_dir):
        (turned / name).write_bytes((run_dir / name).read_bytes())
    lines = (run_dir / "trajectory.csv").read_text().splitlines()
    t = math.radians(4.0)
    body = []
    for line in lines[1:]:
        r = line.split(",")
        x, y = float(r[3]), float(r[4])
        r[3], r[4] = "%.6f" % (math.cos(t) * x - math.sin(t) * y), "%.6f" % (math.sin(t) * x + math.cos(t) * y)
        r[5] = "%.7f" % (float(r[5]) + t)
        body.append(",".join(r))
    (turned / "trajectory.csv").write_text("\n".join([lines[0]] + body) + "\n")
    w = mosaic_pngs(survey, turned, tmp_path / "turned")
    assert w["slam"][0].shape == w["gt"][0].shape and w["slam"][1] == w["gt"][1]
    # the ground truth's mosaic is the same pixels at the same places
    a, b = on_shared_window(truth, w["gt"])
    assert np.array_equal(a, b)
    assert (a[..., 3] > 0).sum() == (truth[0][..., 3] > 0).sum()  # nothing of it was cut off
    # the estimated one is visibly turned: far from the first estimate and from the truth
    a, b = on_shared_window(est, w["slam"])
    moved = mean_colour_difference(a, b)
    off = mean_colour_difference(w["slam"][0], w["gt"][0])
    # ... and turned by the poses: each of its pixels turned back by 4 degrees about the map's origin
    # lands on the same colour of the first estimate's mosaic
    (img, world), (first, first_world) = w["slam"], est
    res = world[0]
    rows_, cols_ = np.nonzero(img[..., 3] > 0)
    x = world[4] + cols_ * res  # pixel centres, image axes (trajectory.csv's): y = -(z-up y)
    y = -(world[5] - rows_ * res)
    bx, by = math.cos(t) * x + math.sin(t) * y, -math.sin(t) * x + math.cos(t) * y
    c = np.rint((bx - first_world[4]) / res).astype(int)
    r = np.rint((-by - first_world[5]) / -res).astype(int)
    ok = (c >= 0) & (r >= 0) & (c < first.shape[1]) & (r < first.shape[0])
    ok[ok] &= first[r[ok], c[ok], 3] > 0
    assert ok.mean() > 0.9
    back = float(np.abs(img[rows_[ok], cols_[ok], :3] - first[r[ok], c[ok], :3]).mean())
    assert moved > 2.0 * close and off > 2.0 * close and back < 0.5 * moved, (close, moved, off, back)
    print("mosaic colour difference: good map vs truth %.2f, turned vs first %.2f, turned vs truth %.2f, "
          "turned back vs first %.2f" % (close, moved, off, back))


def test_exports_take_the_stores_permissions_and_never_write_through_a_planted_link(exported, store, tmp_path):
    """Every file is created exclusively in the output directory and renamed into place: a symbolic
    link planted at a file's temporary name (<file>.tmp) or at its final name never makes the export
    write elsewhere; the files and the directory take the store's permissions (0600 / 0700)."""
    db, _ = store
    assert os.stat(db).st_mode & 0o777 == 0o600
    clean, _ = exported
    outside = tmp_path / "outside"
    outside.mkdir()
    out = tmp_path / "out"
    out.mkdir()
    names = sorted(os.listdir(clean))
    victims = {}
    for i, name in enumerate(names):
        victim = outside / ("tmp_%d" % i)
        victim.write_text("precious %d\n" % i)
        os.symlink(victim, out / (name + ".tmp"))
        victims[victim] = victim.read_text()
        if i % 2:
            final = outside / ("final_%d" % i)
            final.write_text("precious final %d\n" % i)
            os.symlink(final, out / name)
            victims[final] = final.read_text()
    r = run("export_survey", "--db", db, "--out", out, "--origin", ",".join(map(str, ORIGIN)), "--quiet")
    assert r.returncode == 0, r.stderr
    assert {v: v.read_text() for v in victims} == victims
    assert sorted(os.listdir(outside)) == sorted(v.name for v in victims)
    for name in names:
        p = out / name
        assert p.is_file() and not p.is_symlink(), name
        assert os.stat(p).st_mode & 0o777 == 0o600, name
        if not name.endswith((".png", ".tif")):  # GDAL's files: compared as files only
            assert digest(p) == digest(clean / name), name
        assert (out / (name + ".tmp")).is_symlink(), name  # not ours: left as it was
    # A directory the export creates: 0700, like the store's own.
    fresh = tmp_path / "new" / "dir"
    r = run("export_survey", "--db", db, "--out", fresh, "--no-mosaic", "--quiet")
    assert r.returncode == 0, r.stderr
    assert os.stat(tmp_path / "new").st_mode & 0o777 == 0o700
    assert os.stat(fresh).st_mode & 0o777 == 0o700
    assert all(os.stat(fresh / n).st_mode & 0o777 == 0o600 for n in os.listdir(fresh))
