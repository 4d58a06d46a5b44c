"""src/tools/season.py on two small generated dives that overlap, as folders and as bags: one store, one map,
and a summary whose numbers are those of the runs' own outputs (and, for folders, evaluate.py's)."""
import subprocess
import sys
from pathlib import Path

import pytest
from tool_runner import BIN_DIR, TWO_DIVES, make_survey, read_csv as rows, run_tool as run

SEASON = str(Path(__file__).resolve().parents[2] / "src" / "tools" / "season.py")


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
    r = season(base / "a.bag", base / "b.bag", "--out", base / "s", "--", "--camera-mount", "0 0 0 0")
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


def test_bags_summary_numbers_faster_than_real_time(bags, folders, mission):
    summary = check_numbers_against_the_runs(bags, mission)
    assert all(float(s["realtime_x"]) > 1.0 for s in summary)
    assert "ate_m" not in summary[0]  # no ground truth in a bag
    for b, f in zip(summary, rows(folders / "season.csv")):
        assert abs(int(b["keyframes"]) - int(f["keyframes"])) <= 0.05 * int(f["keyframes"])


def test_a_failing_dive_stops_the_season_with_its_reason(mission, tmp_path):
    assert run("folder_to_bag", mission / "a", tmp_path / "a.bag").returncode == 0
    r = season(tmp_path / "a.bag", "--out", tmp_path / "s")  # folder_to_bag's bag has no mounts
    assert r.returncode == 1 and "--camera-mount" in r.stderr, r.stderr
    assert season(tmp_path / "none", "--out", tmp_path / "s").returncode == 2
