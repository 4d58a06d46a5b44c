#!/usr/bin/python3
"""A season of dives into one session store: each dive (a bag or a dataset folder) is run through
offline_slam in the order given, all of them with the same --db, so that the store's reload and its
global loops join the dives where they overlap. Writes one summary of the season:

    season.py [--list FILE] [DIVE ...] --out DIR [--gt DIVE=FOLDER ...] [--db FILE] [--bin-dir DIR] [-- OPTIONS ...]

DIVE         a bag (offline_slam --bag; one dive's bags as A.bag,B.bag) or a dataset folder (--session), in order;
--list FILE  more dives, one a line (# starts a comment; relative paths are the file's)
--out DIR    dives/NN/ (each dive's offline_slam outputs and log), season.db (unless --db), season.md,
             season.csv, season.png (every dive's keyframes, one figure, a panel per map), season.html
             and, when every dive has ground truth, evaluate/ (evaluate.py's report of the last run,
             which holds every dive) and inputs.csv (every dive's, for evaluate.py --inputs)
--gt DIVE=FOLDER  the dataset folder (with gt.csv) of a dive given as DIVE (a bag, or A.bag,B.bag), repeat per
             dive: evaluate.py matches the bag's images to its frames; a folder dive with gt.csv is its own
--db FILE    the store (default DIR/season.db); dives already in it are refused by offline_slam
--           the rest goes to every offline_slam run (e.g. --config F, --camera-mount "0 0 0 0", --ns NS)

Per dive: frames, keyframes, pieces (a tracking loss splits a dive), tracking losses, loops (local,
global within the dive, global to earlier dives), the earlier dives its map holds (joined), the wall
time, for a bag the ratio to real time, and with ground truth the SLAM ATE and e_k of evaluate.py.
Exit status 0, 1 when a dive's run failed (the summary is written for the dives before it) or
evaluate.py refused the ground truth (its reason printed; the summary without errors), 2 on bad arguments.
Doc: doc/tools/season.md.
"""
import argparse
import base64
import csv
import html
import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path


def read_csv(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def find_tool(name, bin_dir):
    here = Path(__file__).resolve().parent  # installed beside offline_slam; in the sources beside evaluate.py
    for d in [bin_dir, os.environ.get("UWMS_BIN_DIR"), here]:
        if d and (Path(d) / name).is_file():
            return str(Path(d) / name)
    found = shutil.which(name)
    if not found:
        sys.exit("season.py: %s not found (pass --bin-dir, the devel space's lib/uw_multislam)" % name)
    return found


def dives_of(args):
    dives = [Path(d) for d in args.dives]
    if args.list:
        base = Path(args.list).resolve().parent
        for line in Path(args.list).read_text().splitlines():
            line = line.split("#", 1)[0].strip()
            if line:
                dives.append(Path(",".join(p if os.path.isabs(p) else str(base / p) for p in line.split(","))))
    return dives


def is_bag(dive):
    """A bag, or one dive's bags named together (a,b): what offline_slam --bag reads."""
    return all(Path(p).is_file() for p in str(dive).split(","))


def run_dive(n, dive, args, slam, extra):
    out = Path(args.out) / "dives" / ("%02d" % n)
    if out.exists():
        shutil.rmtree(out)
    kind = "--bag" if is_bag(dive) else "--session"
    cmd = [slam, kind, str(dive), "--db", args.db, "--out", str(out)] + extra
    t0 = time.monotonic()
    r = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.monotonic() - t0
    out.mkdir(parents=True, exist_ok=True)
    (out / "offline_slam.log").write_text(" ".join(cmd) + "\n" + r.stdout + r.stderr)
    return out, r, wall


def dive_row(n, dive, out, stdout, wall, earlier):
    """The dive's numbers from its run's own outputs; `earlier` maps CSV session -> dive of the runs before."""
    session = read_csv(out / "inputs.csv")[0]["session"]
    frames = int(read_csv(out / "inputs.csv")[0]["frames"])
    pieces = [p for p in read_csv(out / "pieces.csv") if p["session"] == session]
    loops = read_csv(out / "loops.csv")
    mine = [l for l in loops if session in (l["session_a"], l["session_b"])]
    within = [l for l in mine if l["session_a"] == l["session_b"]]
    across = [l for l in mine if l["session_a"] != l["session_b"]]
    traj = read_csv(out / "trajectory.csv")
    maps = {t["map"] for t in traj if t["session"] == session}
    joined = sorted({earlier[t["session"]] for t in traj if t["map"] in maps and t["session"] in earlier})
    ratio = re.search(r"processed in [0-9.]+ s: ([0-9.]+)x real time", stdout)
    return {
        "dive": n, "input": str(dive), "session": session, "frames": frames,
        "keyframes": sum(int(p["keyframes"]) for p in pieces), "pieces": len(pieces),
        "tracking_losses": max(len(pieces) - 1, 0),
        "loops_local": sum(l["kind"] == "local" for l in within),
        "loops_global_within": sum(l["kind"] == "global" for l in within),
        "loops_to_earlier": len(across), "joined_dives": " ".join(map(str, joined)) or "-",
        "maps": len(maps), "time_s": round(wall, 2),
        "realtime_x": float(ratio.group(1)) if ratio else "",
    }


def csv_sessions(rows):
    """The CSV session numbers of each dive in the last run: the store's id of each piece of the dives before it
    (ids are given in order), the one number of the last dive (a run numbers its own dive's pieces alike)."""
    out, first = [], 0
    for i, row in enumerate(rows):
        n = 1 if i == len(rows) - 1 else row["pieces"]
        out.append([str(first + p) for p in range(n)])
        first += row["pieces"]
    return out


def same_dive(a, b):
    return [Path(p).resolve() for p in str(a).split(",")] == [Path(p).resolve() for p in str(b).split(",")]


def truth_folders(dives, pairs, parser):
    """Each dive's ground-truth folder or None: --gt's for the dive it names, else a folder dive's own gt.csv."""
    given = [None] * len(dives)
    for pair in pairs:
        dive, sep, folder = pair.rpartition("=")
        if not sep or not dive or not folder:
            parser.error("--gt %s: give DIVE=FOLDER" % pair)
        hits = [n for n, d in enumerate(dives) if same_dive(d, dive)]
        if not hits:
            parser.error("--gt %s: %s is not a dive of the season" % (pair, dive))
        if not (Path(folder) / "gt.csv").is_file():
            parser.error("--gt %s: %s has no gt.csv" % (pair, folder))
        for n in hits:
            if given[n] is not None:
                parser.error("--gt %s: dive %s has ground truth twice" % (pair, dive))
            given[n] = Path(folder)
    return [g or (d if d.is_dir() and (d / "gt.csv").is_file() else None) for g, d in zip(given, dives)]


def evaluate(args, truths, rows, last_out):
    """evaluate.py over the last run (every dive's sessions): each CSV session scored against its dive's ground-truth
    folder (a bag's frames matched to the folder's by evaluate.py). Returns (metrics or None, refusal or None)."""
    if not truths or None in truths:
        missing = [str(n) for n, t in enumerate(truths) if t is None]
        if len(missing) < len(truths):
            print("season.py: no ground truth for dive(s) %s: no error columns (give --gt DIVE=FOLDER)"
                  % ", ".join(missing), file=sys.stderr)
        return None, None
    folders, inputs = [], []
    for n, (ids, d) in enumerate(zip(csv_sessions(rows), truths)):
        folders += [str(d)] * len(ids)  # the store numbers each piece of a dive
        own = read_csv(Path(args.out) / "dives" / ("%02d" % n) / "inputs.csv")[0]
        inputs += [dict(own, session=i) for i in ids]
    with open(Path(args.out) / "inputs.csv", "w", newline="") as f:  # the last run's has no row for stored dives
        w = csv.DictWriter(f, fieldnames=list(inputs[0]))
        w.writeheader()
        w.writerows(inputs)
    world = [d.parent / "world_gt.csv" for d in truths]
    cmd = [sys.executable, find_tool("evaluate.py", args.bin_dir), "--run", str(last_out), "--report",
           str(Path(args.out) / "evaluate"), "--html", "--inputs", str(Path(args.out) / "inputs.csv")]
    for f in folders:
        cmd += ["--session", f]
    if len({w.parent for w in world}) == 1 and world[0].is_file():
        cmd += ["--world-gt", str(world[0])]
        if (world[0].parent / "loops_gt.csv").is_file():
            cmd += ["--loops-gt", str(world[0].parent / "loops_gt.csv")]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        return None, r.stderr.strip() or r.stdout.strip()
    return json.loads((Path(args.out) / "evaluate" / "metrics.json").read_text()), None


def add_errors(rows, metrics):
    for row, ids in zip(rows, csv_sessions(rows)):
        slam = [metrics["session"].get(i, {}).get("slam", {}) for i in ids]
        row["ate_m"] = " / ".join(_num(s.get("ate_rmse_m")) for s in slam)
        row["ek_inter_m"] = " / ".join(_num(s.get("ek_inter_m")) for s in slam)


def _num(v):
    return "%.4f" % v if isinstance(v, (int, float)) else "n/a"


def plot(last_out, rows, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    traj = read_csv(Path(last_out) / "trajectory.csv")
    dive_of = {s: row["dive"] for row, ids in zip(rows, csv_sessions(rows)) for s in ids}
    maps = sorted({t["map"] for t in traj}, key=int)
    fig, axes = plt.subplots(1, len(maps), figsize=(6 * len(maps), 5), squeeze=False)
    for ax, m in zip(axes[0], maps):
        for s in sorted({t["session"] for t in traj if t["map"] == m}, key=int):
            pts = sorted((int(t["index"]), float(t["x_m"]), float(t["y_m"])) for t in traj if t["session"] == s)
            d = dive_of.get(s, "?")
            ax.plot([p[1] for p in pts], [p[2] for p in pts], ".-", color="C%d" % (d if d != "?" else 9),
                    label="dive %s (session %s)" % (d, s))
        ax.set_title("map %s" % m)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.legend(fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


COLUMNS = ["dive", "input", "frames", "keyframes", "pieces", "tracking_losses", "loops_local",
           "loops_global_within", "loops_to_earlier", "joined_dives", "maps", "time_s", "realtime_x"]


def write_summary(out, rows, maps, with_errors):
    cols = COLUMNS + (["ate_m", "ek_inter_m"] if with_errors else [])
    with open(out / "season.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    lines = ["# Season: %d dives, %d maps" % (len(rows), maps), "",
             "| " + " | ".join(cols) + " |", "|" + " --- |" * len(cols)]
    lines += ["| " + " | ".join(str(r.get(c, "")) for c in cols) + " |" for r in rows]
    (out / "season.md").write_text("\n".join(lines) + "\n")
    table = "<table border=1><tr>%s</tr>%s</table>" % (
        "".join("<th>%s</th>" % c for c in cols),
        "".join("<tr>%s</tr>" % "".join("<td>%s</td>" % html.escape(str(r.get(c, ""))) for c in cols) for r in rows))
    png = base64.b64encode((out / "season.png").read_bytes()).decode() if (out / "season.png").exists() else ""
    report = '<p><a href="evaluate/report.html">evaluate.py report</a></p>' if with_errors else ""
    (out / "season.html").write_text(
        "<!DOCTYPE html><html><head><meta charset='utf-8'><title>Season</title></head><body><h1>Season: %d dives, "
        "%d maps</h1>%s%s<img src='data:image/png;base64,%s' alt='every dive'></body></html>\n"
        % (len(rows), maps, table, report, png))
    print("\n".join(lines))


def main(argv):
    own, extra = (argv[:argv.index("--")], argv[argv.index("--") + 1:]) if "--" in argv else (argv, [])
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    parser.add_argument("dives", nargs="*")
    parser.add_argument("--list")
    parser.add_argument("--out", required=True)
    parser.add_argument("--gt", action="append", default=[], metavar="DIVE=FOLDER")
    parser.add_argument("--db")
    parser.add_argument("--bin-dir")
    args = parser.parse_args(own)
    dives = dives_of(args)
    if not dives:
        parser.error("no dive: give bags or folders, or --list FILE")
    for d in dives:
        if not (is_bag(d) or d.is_dir()):
            parser.error("%s: no such bag or folder" % d)
    truths = truth_folders(dives, args.gt, parser)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    args.db = args.db or str(out / "season.db")
    slam = find_tool("offline_slam", args.bin_dir)
    rows, earlier, status, last_out = [], {}, 0, None
    for n, dive in enumerate(dives):
        run_out, r, wall = run_dive(n, dive, args, slam, extra)
        if r.returncode != 0:
            print("season.py: dive %d (%s) failed (exit %d): %s" % (n, dive, r.returncode, r.stderr.strip()),
                  file=sys.stderr)
            status = 1
            break
        row = dive_row(n, dive, run_out, r.stdout, wall, earlier)
        rows.append(row)
        first = sum(x["pieces"] for x in rows[:-1])
        earlier.update({str(first + p): n for p in range(row["pieces"])})
        last_out = run_out
        print("dive %d %s: %d frames, %d keyframes, %d pieces, %.1f s" % (n, dive, row["frames"], row["keyframes"],
                                                                       row["pieces"], wall))
    maps = 0
    if last_out:
        maps = len({t["map"] for t in read_csv(last_out / "trajectory.csv")})
        plot(last_out, rows, out / "season.png")
    metrics = None
    if last_out and status == 0:
        metrics, refusal = evaluate(args, truths, rows, last_out)
        if refusal:
            print("season.py: evaluate.py refused the ground truth, no error columns: %s" % refusal, file=sys.stderr)
            status = 1
    if metrics:
        add_errors(rows, metrics)
    write_summary(out, rows, maps, metrics is not None)
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
