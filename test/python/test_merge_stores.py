"""merge_stores: two stores made separately, one session each, merged into one,
against one offline_slam run over both folders into one store. Also every refusal (OUT exists, an
input twice, hash settings that differ, a recording session) with the inputs untouched and no
OUT or temporary file left."""
import hashlib
import math
import os
import shutil
import sqlite3

import pytest
from tool_runner import make_survey, read_csv as rows, run_tool as run
from test_offline_slam import SURVEY


def md5(path):
    with open(path, "rb") as f:
        return hashlib.md5(f.read()).hexdigest()


@pytest.fixture(scope="module")
def stores(tmp_path_factory):
    base = tmp_path_factory.mktemp("merge")
    make_survey(base, SURVEY)
    made = {}
    for name, folders in {"a": ["a"], "b": ["b"], "both": ["a", "b"]}.items():
        args = []
        for f in folders:
            args += ["--session", base / "m" / f]
        r = run("offline_slam", *args, "--out", base / ("run_" + name), "--db", base / (name + ".db"), "--quiet")
        assert r.returncode == 0, r.stderr
        made[name] = base / (name + ".db")
    return base, made


@pytest.fixture(scope="module")
def merged(stores):
    base, made = stores
    before = {k: md5(p) for k, p in made.items()}
    out = base / "merged.db"
    r = run("merge_stores", out, made["a"], made["b"], "--vehicle", "auv1", "--vehicle", "auv2", "--dive", "d7")
    assert r.returncode == 0, r.stdout + r.stderr
    return base, made, before, out, r


def summary(stdout):
    line = [l for l in stdout.splitlines() if l.startswith("merge_stores ")][-1]
    return dict(kv.split("=", 1) for kv in line.split()[1:])


def store_maps(path):
    """map id -> (chain of session ids, links as (x, y, yaw)) read straight from the store's tables."""
    db = sqlite3.connect("file:%s?mode=ro" % path, uri=True)
    try:
        maps = {}
        for (m,) in db.execute("SELECT id FROM maps ORDER BY id"):
            chain = [s for (s,) in db.execute("SELECT session FROM map_sessions WHERE map=? ORDER BY position", (m,))]
            links = list(db.execute("SELECT x, y, yaw FROM links WHERE map=? ORDER BY position", (m,)))
            maps[m] = (chain, links)
        return maps
    finally:
        db.close()


def map_poses(base, store, name):
    """export_survey's per-map CSV of a store: (session name, keyframe) -> (x, y, yaw)."""
    out = base / ("export_" + name)
    r = run("export_survey", "--db", store, "--out", out, "--no-mosaic", "--quiet")
    assert r.returncode == 0, r.stderr
    db = sqlite3.connect("file:%s?mode=ro" % store, uri=True)
    names = dict(db.execute("SELECT id, name FROM sessions"))
    db.close()
    maps = sorted(p for p in os.listdir(out) if p.startswith("map_") and p.endswith(".csv"))
    assert len(maps) == 1, maps  # one map: both sessions joined
    poses = {}
    for row in rows(out / maps[0]):
        poses[(os.path.basename(names[int(row["session"])]), int(row["keyframe"]))] = (
            float(row["x_m"]), float(row["y_m"]), float(row["yaw_rad"]))
    return poses


def test_merge_joins_the_two_stores_like_one_run(merged):
    base, made, _, out, r = merged
    s = summary(r.stdout)
    assert s["inputs"] == "2" and s["sessions"] == "2" and s["maps"] == "1" and s["joins"] == "1", r.stdout
    assert int(s["new_loops"]) >= 2, r.stdout  # join_policy consistent's minimum set
    # The same map as one run over both folders: one map, one link, the same poses.
    one = store_maps(made["both"])
    two = store_maps(out)
    assert len(one) == 1 and len(two) == 1
    (chain1, links1), = one.values()
    (chain2, links2), = two.values()
    assert len(chain1) == len(chain2) == 2 and len(links1) == len(links2) == 1
    # The loops are the same ones (the same stored hashes and features; the live run's query
    # features are the extractor's, stored losslessly), and the link is made from the same
    # consistent set in the same keyframe order. join_policy consistent waits for a loop to b's
    # second keyframe (the spread), so the link also rests on b's first motion: its odometry in the
    # one run (b was recording), b's own optimised motion in the merge (b complete, with its local
    # loops). Measured 2026-11-25: 3.7e-6 m in x, 5.0e-5 m in y, 7.7e-7 rad; a wrong link or a
    # lost loop moves b by cm.
    for u, v in zip(links1[0], links2[0]):
        assert abs(u - v) < 2e-4, (links1, links2)
    p1 = map_poses(base, made["both"], "both")
    p2 = map_poses(base, out, "merged")
    assert p1.keys() == p2.keys() and len(p1) > 10
    # After the final optimisation both solve the same problem (odometry, link, loops); only the
    # order the loops came in differs (one run: interleaved with b's keyframes). 1 mm bounds the
    # solver's stopping tolerance on this 9 m survey; a wrong link or a lost loop moves b by cm.
    worst = max(math.hypot(p1[k][0] - p2[k][0], p1[k][1] - p2[k][1]) for k in p1)
    assert worst < 1e-3, worst


def test_inputs_untouched_and_provenance_kept(merged):
    base, made, before, out, _ = merged
    assert {k: md5(p) for k, p in made.items()} == before
    for p in (made["a"], made["b"]):
        for suffix in ("-wal", "-shm", ".lock"):
            assert not os.path.exists(str(p) + suffix) or suffix == ".lock", p  # nothing new beside them
    assert not [f for f in os.listdir(base) if ".partial-" in f]
    db = sqlite3.connect("file:%s?mode=ro" % out, uri=True)
    prov = list(db.execute("SELECT session, source_file, source_session, vehicle, dive FROM provenance ORDER BY session"))
    sessions = list(db.execute("SELECT id, name, state FROM sessions ORDER BY id"))
    db.close()
    # --dive d7 names the first input's dive; the second's defaults to its session's name.
    assert [(p[1], p[3], p[4]) for p in prov] == [(str(made["a"]), "auv1", "d7"),
                                                  (str(made["b"]), "auv2", sessions[1][1])]
    assert [p[0] for p in prov] == [s[0] for s in sessions]
    assert all(s[2] == "finished" for s in sessions)


def test_merged_store_loads_in_offline_slam(merged):
    """offline_slam --db restores the merged store (both sessions, one map) and recognises a
    folder already in it."""
    base, _, _, out, _ = merged
    copy = base / "merged_copy.db"
    shutil.copy(out, copy)
    r = run("offline_slam", "--session", base / "m" / "b", "--out", base / "run_again", "--db", copy)
    assert r.returncode != 0
    assert "already" in (r.stdout + r.stderr), r.stdout + r.stderr


def damaged_copy(src, dst, *sql):
    """A copy of the store src at dst with the SQL statements applied."""
    shutil.copy(src, dst)
    db = sqlite3.connect(str(dst))
    for statement in sql:
        db.execute(statement)
    db.commit()
    db.close()
    return dst


def test_refusals_leave_nothing(stores, tmp_path):
    base, made = stores
    before = {k: md5(p) for k, p in made.items()}
    out = tmp_path / "o.db"
    out.write_bytes(b"precious")
    r = run("merge_stores", out, made["a"], made["b"])
    assert r.returncode == 1 and "never overwrites" in r.stderr, r.stderr
    assert out.read_bytes() == b"precious"
    out.unlink()
    r = run("merge_stores", out, made["a"], made["a"])
    assert r.returncode == 1 and "given twice" in r.stderr, r.stderr
    # The same store through a hard link or a symbolic link: the same file, refused naming both.
    hard, soft = tmp_path / "ahard.db", tmp_path / "asoft.db"
    os.link(made["a"], hard)
    os.symlink(made["a"], soft)
    for other in (hard, soft):
        r = run("merge_stores", out, made["a"], other)
        lines = [l for l in r.stderr.splitlines() if l.strip()]
        assert r.returncode == 1 and len(lines) == 1 and "given twice" in lines[0], r.stderr
        assert str(other) in lines[0] and str(made["a"]) in lines[0], r.stderr
    hard.unlink()
    soft.unlink()
    # A store made with other hash settings.
    cfg = tmp_path / "seed.yaml"
    cfg.write_text("loops:\n  global:\n    projection_seed: 7\n")
    other = tmp_path / "other.db"
    r = run("offline_slam", "--session", base / "m" / "b", "--out", tmp_path / "run", "--db", other,
            "--config", cfg, "--quiet")
    assert r.returncode == 0, r.stderr
    r = run("merge_stores", out, made["a"], other)
    assert r.returncode == 1 and "projection_seed 7" in r.stderr and "projection_seed 20231122" in r.stderr, r.stderr
    # A session still recording (an interrupted run).
    rec = damaged_copy(made["b"], tmp_path / "recording.db", "UPDATE sessions SET state = 'recording'")
    r = run("merge_stores", out, made["a"], rec)
    assert r.returncode == 1 and "still recording" in r.stderr, r.stderr
    # A session state outside the schema's CHECK (written with the check off): damaged, not
    # "still recording"; a damaged projections row: not "other projection vectors".
    odd = damaged_copy(made["b"], tmp_path / "odd_state.db", "PRAGMA ignore_check_constraints = ON",
                       "UPDATE sessions SET state = 'done'")
    r = run("merge_stores", out, made["a"], odd)
    assert r.returncode == 1 and "column 'state' of table 'sessions' holds 'done' (damaged" in r.stderr, r.stderr
    cut = damaged_copy(made["b"], tmp_path / "cut_projections.db",
                       "UPDATE meta SET value = substr(value, 1, 300) WHERE key = 'projections'")
    r = run("merge_stores", out, made["a"], cut)
    assert r.returncode == 1 and "%s: its meta table is damaged (projections: HALOC projections: " % cut in r.stderr, r.stderr
    assert "other projection vectors" not in r.stderr, r.stderr
    # A damaged row (a loop naming a session the store does not hold): refused as every reader
    # refuses it, by name (the copy took it without a word, one loop short).
    dangling = damaged_copy(made["both"], tmp_path / "dangling.db",
                            "UPDATE loops SET session_a = 77 WHERE id = (SELECT min(id) FROM loops)")
    db = sqlite3.connect(str(dangling))
    (loop,) = db.execute("SELECT id FROM loops WHERE session_a = 77").fetchone()
    db.close()
    r = run("merge_stores", out, made["a"], dangling)
    assert r.returncode == 1 and "loop %d (session 77" % loop in r.stderr, r.stderr
    assert "names a session the store does not hold" in r.stderr, r.stderr
    r = run("merge_stores", out, made["a"])
    assert r.returncode == 2, r.stderr
    assert not out.exists()
    assert not [f for f in os.listdir(tmp_path) if ".partial-" in f]
    assert {k: md5(p) for k, p in made.items()} == before


def test_copy_only_keeps_two_maps(stores, tmp_path):
    _, made = stores
    r = run("merge_stores", tmp_path / "c.db", made["a"], made["b"], "--no-loops")
    assert r.returncode == 0, r.stderr
    s = summary(r.stdout)
    assert s["maps"] == "2" and s["joins"] == "0" and s["new_loops"] == "0", r.stdout
    assert len(store_maps(tmp_path / "c.db")) == 2


def test_detect_loops_joins_stored_sessions_without_a_new_one(merged, tmp_path):
    """Loops are searched among stored sessions (offline_slam --db --detect-loops,
    no folder): the copy-only merge's two maps are joined like merge_stores joins them, and a
    second search finds only loops the store already holds."""
    _, made, _, loops_db, _ = merged
    db = tmp_path / "copy_only.db"
    r = run("merge_stores", db, made["a"], made["b"], "--no-loops", "--quiet")
    assert r.returncode == 0, r.stderr
    assert len(store_maps(db)) == 2
    r = run("offline_slam", "--db", db, "--detect-loops", "--out", tmp_path / "o1")
    assert r.returncode == 0, r.stdout + r.stderr
    line = [l for l in r.stdout.splitlines() if l.startswith("detect-loops")][0]
    assert "0 already stored" in line and "1 joins" in line, line
    maps = store_maps(db)
    assert len(maps) == 1
    (_, links), = maps.values()
    (_, merged_links), = store_maps(loops_db).values()
    for u, v in zip(links[0], merged_links[0]):  # the same loops in the same order: the same link
        assert abs(u - v) < 1e-9, (links, merged_links)
    assert len(rows(tmp_path / "o1" / "links.csv")) == 1
    r = run("offline_slam", "--db", db, "--detect-loops", "--out", tmp_path / "o2")
    assert r.returncode == 0, r.stdout + r.stderr
    line = [l for l in r.stdout.splitlines() if l.startswith("detect-loops")][0]
    found, held = int(line.split(" loops (")[0].split()[-1]), int(line.split(" loops (")[1].split()[0])
    assert found > 5 and held == found and " 0 accepted" in line, line
    r = run("offline_slam", "--detect-loops", "--out", tmp_path / "o3")
    assert r.returncode == 2 and "--db" in r.stderr


def test_localise_only_leaves_the_store_byte_identical(stores, tmp_path):
    """Offline equivalent of set_mode localisation: offline_slam --localise-only
    over folder b against store a (session 0) tracks b, finds its global loops to session 0, does not
    join (automatic joins wait), writes its outputs, and leaves the store byte-identical; the same run
    without the flag writes to the store (so the md5 check can fail). Bad combinations exit 2."""
    base, made = stores
    db = tmp_path / "a.db"
    shutil.copy(made["a"], db)
    before = md5(db)
    r = run("offline_slam", "--session", base / "m" / "b", "--db", db, "--localise-only", "--out", tmp_path / "loc")
    assert r.returncode == 0, r.stdout + r.stderr
    assert "localisation mode" in r.stdout
    assert md5(db) == before, "--localise-only changed the store"
    trajectory = rows(tmp_path / "loc" / "trajectory.csv")
    assert {int(t["session"]) for t in trajectory} == {0, 1}
    assert {int(t["map"]) for t in trajectory if int(t["session"]) == 1} == {1}  # no join
    across = [l for l in rows(tmp_path / "loc" / "loops.csv") if l["kind"] == "global"]
    assert len(across) >= 5, across  # found against the stored session all the same
    r = run("offline_slam", "--session", base / "m" / "b", "--db", db, "--out", tmp_path / "map", "--quiet")
    assert r.returncode == 0, r.stderr
    assert md5(db) != before
    for extra in (["--detect-loops"], ["--interrupted", "finish"]):
        r = run("offline_slam", "--session", base / "m" / "b", "--db", db, "--localise-only", *extra,
                "--out", tmp_path / "x")
        assert r.returncode == 2 and "--localise-only" in r.stderr, r.stderr
    r = run("offline_slam", "--session", base / "m" / "b", "--localise-only", "--out", tmp_path / "y")
    assert r.returncode == 2 and "--db" in r.stderr, r.stderr
    r = run("offline_slam", "--session", base / "m" / "b", "--db", tmp_path / "none.db", "--localise-only",
            "--out", tmp_path / "z")
    assert r.returncode == 1 and "would not be created" in r.stderr, r.stderr
    assert not (tmp_path / "none.db").exists()


def test_add_link_offline_finds_or_takes_the_link_and_a_refusal_adds_none(stores, tmp_path):
    """Offline equivalent of add_link: offline_slam --db --add-link on the two
    stored sessions of a copy-only merge. "Find it" measures the link between two keyframes that
    overlap in the ground truth (loops_gt.csv) by RANSAC on their stored features, within 2 cm and
    0.01 rad of world_gt.csv; a given pose is taken as given; both are stored loops. One bad link
    in the list adds none of them (store byte-identical, no OUT); bad specs exit 2."""
    base, made = stores
    db = tmp_path / "two.db"
    r = run("merge_stores", db, made["a"], made["b"], "--no-loops", "--quiet")
    assert r.returncode == 0, r.stderr
    keyframes = {s: [int(t["index"]) for t in rows(base / ("run_" + n) / "trajectory.csv") if t["session"] == "0"]
                 for s, n in ((0, "a"), (1, "b"))}
    ia, ib = next((int(g["index_a"]), int(g["index_b"])) for g in rows(base / "m" / "loops_gt.csv")
                  if g["session_a"] == "0" and g["session_b"] == "1" and int(g["index_a"]) in keyframes[0]
                  and int(g["index_b"]) in keyframes[1])
    ka, kb = keyframes[0].index(ia), keyframes[1].index(ib)
    world = {(int(g["session"]), int(g["index"])): (float(g["x_m"]), float(g["y_m"]), float(g["yaw_rad"]))
             for g in rows(base / "m" / "world_gt.csv")}
    a, b = world[(0, ia)], world[(1, ib)]
    c, s = math.cos(a[2]), math.sin(a[2])
    truth = (c * (b[0] - a[0]) + s * (b[1] - a[1]), -s * (b[0] - a[0]) + c * (b[1] - a[1]),
             math.remainder(b[2] - a[2], math.tau))

    def loops_in(path):
        with sqlite3.connect(path) as con:
            return con.execute("SELECT COUNT(*) FROM loops").fetchone()[0]

    before, loops_before = md5(db), loops_in(db)
    found = f"0:{ka}:1:{kb}"
    r = run("offline_slam", "--db", db, "--add-link", found, "--add-link", "0:0:9:0", "--out", tmp_path / "bad")
    assert r.returncode == 1 and "no link added" in r.stderr and "NOT_FOUND" in r.stderr, r.stderr
    assert md5(db) == before and not (tmp_path / "bad").exists()
    for spec in ("0:0:1", "0:0:1:0:0.1:0:0:0:0.01", "0:x:1:0", "0:0:1:0:nan:0:0:0.01:0.01"):
        r = run("offline_slam", "--db", db, "--add-link", spec, "--out", tmp_path / "bad")
        assert r.returncode == 2 and "--add-link" in r.stderr, (spec, r.stderr)
    r = run("offline_slam", "--db", db, "--add-link", found, "--localise-only", "--out", tmp_path / "bad")
    assert r.returncode == 2 and "--localise-only" in r.stderr, r.stderr
    r = run("offline_slam", "--add-link", found, "--out", tmp_path / "bad")
    assert r.returncode == 2 and "--db" in r.stderr, r.stderr
    assert md5(db) == before

    r = run("offline_slam", "--db", db, "--add-link", found, "--add-link", f"0:{ka}:1:{kb}:0.1:0.2:0.3:0.01:0.01",
            "--out", tmp_path / "o")
    assert r.returncode == 0, r.stdout + r.stderr
    line = [l for l in r.stdout.splitlines() if l.startswith("add-link") and "found by RANSAC" in l][0]
    x, y, yaw = (float(v) for v in line.split("(")[1].split(")")[0].split(","))
    print(f"\nadd-link {found}: ({x:.4f}, {y:.4f}, {yaw:.4f}) against the truth "
          f"({truth[0]:.4f}, {truth[1]:.4f}, {truth[2]:.4f})")
    assert math.hypot(x - truth[0], y - truth[1]) < 0.02 and abs(math.remainder(yaw - truth[2], math.tau)) < 0.01
    assert "(0.1000, 0.2000, 0.3000) as given" in r.stdout
    assert loops_in(db) == loops_before + 2
