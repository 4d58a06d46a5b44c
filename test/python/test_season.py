"""src/tools/season.py on two small generated dives that overlap, as folders and as bags: one store, one map,
and a summary whose numbers are those of the runs' own outputs and evaluate.py's errors, the bags scored against
their folders (--gt) as the folders are; ground truth that is not the bag's folder refused."""
import csv
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from tool_runner import BIN_DIR, TWO_DIVES, make_survey, read_csv as rows, run_tool as run

SEASON = str(Path(__file__).resolve().parents[2] / "src" / "tools" / "season.py")
EVALUATE = str(Path(__file__).resolve().parents[2] / "src" / "tools" / "evaluate.py")


def season(*args):
    return subprocess.run([sys.executable, SEASON, "--bin-dir", BIN_DIR, *map(str, args)], capture_output=True,
                          text=True, timeout=300)


@pytest.fixture(scope="module")
def mission(tmp_path_factory):
    return make_survey(tmp_path_factory.mktemp("season"), TWO_DIVES)


@pytest.fixture(scope="module")
def folders(mission, tmp_path_factory):
    out = tmp_path_factory.mktemp("folders")
    listing = out / "dives.txt"
    listing.write_text("# the season\n%s\n%s\n" % (mission / "a", mission / "b"))
    r = season("--list", listing, "--out", out / "s")
    assert r.returncode == 0, r.stderr
    return out / "s"


@pytest.fixture(scope="module")
def bags(mission, tmp_path_factory):
    base = tmp_path_factory.mktemp("bags")
    for name in ("a", "b"):
        assert run("folder_to_bag", mission / name, base / (name + ".bag")).returncode == 0
    r = season(base / "a.bag", base / "b.bag", "--out", base / "s", "--gt", "%s=%s" % (base / "a.bag", mission / "a"),
               "--gt", "%s=%s" % (base / "b.bag", mission / "b"), "--", "--camera-mount", "0 0 0 0")
    assert r.returncode == 0, r.stderr
    return base / "s"


def check_numbers_against_the_runs(out, mission):
    summary = rows(out / "season.csv")
    assert [int(s["dive"]) for s in summary] == [0, 1]
    for s, name in zip(summary, ("a", "b")):
        run_out = out / "dives" / ("%02d" % int(s["dive"]))
        session = rows(run_out / "inputs.csv")[0]["session"]
        assert int(s["frames"]) == len(rows(mission / name / "frames.csv"))
        mine = [t for t in rows(run_out / "trajectory.csv") if t["session"] == session]
        assert int(s["keyframes"]) == len(mine) > 2
        pieces = [p for p in rows(run_out / "pieces.csv") if p["session"] == session]
        assert int(s["pieces"]) == len(pieces) and int(s["tracking_losses"]) == len(pieces) - 1
        loops = [l for l in rows(run_out / "loops.csv") if session in (l["session_a"], l["session_b"])]
        counted = int(s["loops_local"]) + int(s["loops_global_within"]) + int(s["loops_to_earlier"])
        assert counted == len(loops)
    # The second dive overlaps the first: global loops to it, and the store joined them into one map.
    assert int(summary[0]["loops_to_earlier"]) == 0 and summary[0]["joined_dives"] == "-"
    assert int(summary[1]["loops_to_earlier"]) > 0 and summary[1]["joined_dives"] == "0"
    last = rows(out / "dives" / "01" / "trajectory.csv")
    assert {t["session"] for t in last} == {"0", "1"} and {t["map"] for t in last} == {"0"}
    assert "# Season: 2 dives, 1 maps" in (out / "season.md").read_text()
    page = (out / "season.html").read_text()
    assert "<table" in page and "data:image/png;base64," in page
    assert (out / "season.png").read_bytes()[:4] == b"\x89PNG"
    return summary


def test_folders_summary_numbers_and_errors(folders, mission):
    summary = check_numbers_against_the_runs(folders, mission)
    metrics = {(m["scope"], m["id"], m["estimate"], m["metric"]): m["value"]
               for m in rows(folders / "evaluate" / "metrics.csv")}
    for s in summary:
        ate = float(metrics[("session", s["dive"], "slam", "ate_rmse_m")])
        assert float(s["ate_m"]) == pytest.approx(ate, abs=5e-5)
        assert ate < 0.05
    assert "evaluate/report.html" in (folders / "season.html").read_text()


def metrics_of(report):
    return {(m["scope"], m["id"], m["estimate"], m["metric"]): m["value"] for m in rows(report / "metrics.csv")}


def test_bags_summary_numbers_faster_than_real_time(bags, folders, mission):
    summary = check_numbers_against_the_runs(bags, mission)
    assert all(float(s["realtime_x"]) > 1.0 for s in summary)
    for b, f in zip(summary, rows(folders / "season.csv")):
        assert abs(int(b["keyframes"]) - int(f["keyframes"])) <= 0.05 * int(f["keyframes"])


def test_bags_scored_against_their_folders_give_the_folders_errors(bags, folders):
    """The bags' poses agree with the folders' to 1 mm, their frames are matched to the folders' by position:
    the same ATE and e_k, per dive and for the map, to 1 mm."""
    bag, folder = metrics_of(bags / "evaluate"), metrics_of(folders / "evaluate")
    for scope, ident in [("session", "0"), ("session", "1"), ("map", "0")]:
        for metric in ("ate_rmse_m", "ek_inter_m"):
            f, b = folder[(scope, ident, "slam", metric)], bag[(scope, ident, "slam", metric)]
            assert f != "n/a" and float(b) == pytest.approx(float(f), abs=1e-3), (scope, ident, metric)
        for metric in ("n_keyframes", "ek_inter_pairs", "ek_intra_pairs"):
            assert bag[(scope, ident, "slam", metric)] == folder[(scope, ident, "slam", metric)], (scope, ident, metric)
    assert float(bag[("session", "1", "slam", "ek_intra_m")]) == pytest.approx(
        float(folder[("session", "1", "slam", "ek_intra_m")]), abs=1e-3)
    for b, f in zip(rows(bags / "season.csv"), rows(folders / "season.csv")):
        assert b["ate_m"] != "n/a" and float(b["ate_m"]) == pytest.approx(float(f["ate_m"]), abs=1e-3)
        assert float(b["ek_inter_m"]) == pytest.approx(float(f["ek_inter_m"]), abs=1e-3)
    notes = (bags / "evaluate" / "metrics.md").read_text()
    assert "bag %s matched to" % (bags.parent / "a.bag") in notes and "1700000000.000 s after" in notes


def evaluate(run, inputs, *truth):
    """evaluate.py over a run with the season's inputs.csv; truth: folders (each a --session) or --mission DIR."""
    args = [sys.executable, EVALUATE, "--run", run, "--inputs", inputs, "--report", run.parent / "r", "--no-plots"]
    if truth[0] != "--mission":
        truth = [a for f in truth for a in ("--session", f)]
    args += truth
    return subprocess.run(list(map(str, args)), capture_output=True, text=True, timeout=120)


def shift_indexes(src, dst, columns):
    """src's CSV rows into dst, with 100 added to each index column whose session column (None: every row) is 0."""
    table = rows(src)
    for row in table:
        for session, index in columns:
            if session is None or row[session] == "0":
                row[index] = str(int(row[index]) + 100)
    with open(dst, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(table[0]))
        w.writeheader()
        w.writerows(table)


def test_a_bags_frames_are_its_folders_by_position_not_by_index(bags, mission, tmp_path):
    """Dive a's frames numbered from 100 in its folder (and the world's files): image k of the bag is the folder's
    frame k, scored as with the frames numbered from 0."""
    shifted = tmp_path / "m"
    shutil.copytree(mission, shifted)
    for name in ("frames.csv", "gt.csv"):
        shift_indexes(mission / "a" / name, shifted / "a" / name, [(None, "index")])
    shift_indexes(mission / "world_gt.csv", shifted / "world_gt.csv", [("session", "index")])
    shift_indexes(mission / "loops_gt.csv", shifted / "loops_gt.csv", [("session_a", "index_a"),
                                                                       ("session_b", "index_b")])
    run = tmp_path / "run"
    shutil.copytree(bags / "dives" / "01", run)
    r = evaluate(run, bags / "inputs.csv", "--mission", shifted)
    assert r.returncode == 0, r.stderr
    shifted_metrics, metrics = metrics_of(tmp_path / "r"), metrics_of(bags / "evaluate")
    for key in [("session", "0", "slam", "ate_rmse_m"), ("session", "0", "slam", "ek_inter_m"),
                ("map", "0", "slam", "ate_rmse_m"), ("session", "0", "slam", "ek_inter_pairs")]:
        assert shifted_metrics[key] == metrics[key] != "n/a", key


def test_ground_truth_that_is_not_the_bags_folder_is_refused(bags, mission, tmp_path):
    run, inputs = bags / "dives" / "01", bags / "inputs.csv"
    r = evaluate(run, inputs, mission / "b", mission / "a")  # each the other dive's folder
    assert r.returncode == 1 and "session 0 of the run was read from bag" in r.stderr, r.stderr
    assert "24 images over 23.000 s" in r.stderr and "has 17 frames over 16.000 s" in r.stderr, r.stderr
    fewer = tmp_path / "a"
    shutil.copytree(mission / "a", fewer)
    for name in ("frames.csv", "gt.csv"):  # its last frame left out
        (fewer / name).write_text("\n".join((fewer / name).read_text().splitlines()[:-1]) + "\n")
    r = evaluate(run, inputs, fewer, mission / "b")
    assert r.returncode == 1 and "24 images" in r.stderr and "has 23 frames" in r.stderr, r.stderr
    assert not (run.parent / "r" / "metrics.csv").exists()
    for altitude, refused in (("2.5", True), ("nan", False)):  # one frame's altitude: another recording's, or none
        other = tmp_path / ("alt_" + altitude)
        shutil.copytree(mission / "a", other)
        lines = (other / "frames.csv").read_text().splitlines()
        cells = lines[5].split(",")
        lines[5] = ",".join(cells[:3] + [altitude])
        (other / "frames.csv").write_text("\n".join(lines) + "\n")
        r = evaluate(run, inputs, other, mission / "b")
        if refused:
            assert r.returncode == 1 and "mean altitude 2.0017 m) but" in r.stderr, r.stderr
        else:  # the bag's frame has an altitude interpolated from its neighbours: not compared, said in the notes
            assert r.returncode == 0, r.stderr
            assert "mean altitude not compared" in (run.parent / "r" / "metrics.md").read_text()
    # Through season.py: the summary without error columns, the refusal printed, exit status 1.
    r = season(bags.parent / "a.bag", "--out", tmp_path / "s", "--gt", "%s=%s" % (bags.parent / "a.bag", mission / "b"),
               "--", "--camera-mount", "0 0 0 0")
    assert r.returncode == 1 and "refused the ground truth" in r.stderr and "has 17 frames" in r.stderr, r.stderr
    assert "ate_m" not in rows(tmp_path / "s" / "season.csv")[0]
    r = season(bags.parent / "a.bag", "--out", tmp_path / "t", "--gt", "%s=%s" % (tmp_path / "c.bag", mission / "a"))
    assert r.returncode == 2 and "is not a dive of the season" in r.stderr, r.stderr


def test_a_failing_dive_stops_the_season_with_its_reason(mission, tmp_path):
    assert run("folder_to_bag", mission / "a", tmp_path / "a.bag").returncode == 0
    r = season(tmp_path / "a.bag", "--out", tmp_path / "s")  # folder_to_bag's bag has no mounts
    assert r.returncode == 1 and "--camera-mount" in r.stderr, r.stderr
    assert season(tmp_path / "none", "--out", tmp_path / "s").returncode == 2
