#!/usr/bin/python3
"""bench_nav: a nav prior must never make a map worse than no nav.

For each row of test/nav_bench.yaml (a make_survey spec: black-outs, turns, nav drift, ENU/NED nav,
two sessions), renders the flight with make_survey, runs offline_slam with --nav on and --nav off,
scores both with evaluate.py and prints one markdown table:

  map ATE      RMS of the keyframe position errors of trajectory.csv over the keyframes whose frame
               sees the seabed (outside the row's blank/occluded stretches), each keyframe in the
               frame of its visual group as evaluate.py puts the ground truth in a map's frame (the
               ground-truth pose of the group's first keyframe; no fitting). A visual group is a
               set of pieces that accepted visual loops (loops.csv) tie together: a map without nav
               placements; a piece or session the nav placed and no loop reached is a group of its
               own, its placement judged apart (placed). Without nav the blind frames are no
               keyframes at all, so this is the part of the map both runs have
  one frame    with nav: the same in the frame of each map (nav placements included): how far the
               map is from the world where the nav alone placed a part of it
  blind        the same over the keyframes inside the stretches (with nav only: dead-reckoned)
  ratio        map ATE with nav / without nav
  pieces       the sessions offline_slam made (pieces.csv rows: a tracking loss starts a piece)
  maps         the maps they end in (pieces rejoined by loops share a map)
  refused      loops the back-end refused, at the end of the run (loops_refused.csv) and, in
               brackets, on arrival (the log's "loop a -> b refused" lines of the intra-map gate;
               some are taken back after a solve)
  nav          with nav: frames carried by the nav / nav steps refused as implausible / fallbacks
  placed       with nav: nav placements (nav_placements.csv), and the worst of them as its error
               against the ground truth's relative pose of its two keyframes / its sigma (mm)
  rule         PASS when map ATE with nav <= map ATE without nav + 5 mm

Rows with `twin_of` (the same flight, nav written in another frame) are also compared keyframe by
keyframe with their twin's --nav on trajectory: the largest position difference is printed.

Exit status 0 when every row passes, 1 when one fails, 2 on bad arguments or a failed tool run.
usage: bench_nav.py --bin DIR --out DIR [--rows NAME,...] [--spec FILE] [--config FILE]
"""
import argparse
import csv
import math
import os
import re
import subprocess
import sys
import time

import yaml

RULE_MARGIN_M = 0.005
REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(REPO, "src", "tools"))
import evaluate  # noqa: E402  (the scoring of evaluate.py, used as a module)
from atomic_file import AtomicFile, write_atomically  # noqa: E402  (the tools' safe writer)


def read_csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def run(cmd, log):
    with AtomicFile(log, "wb") as out:
        r = subprocess.run([str(c) for c in cmd], stdout=out, stderr=subprocess.STDOUT)
    if r.returncode != 0:
        with open(log) as f:
            tail = f.read().strip().splitlines()[-3:]
        raise RuntimeError("%s failed (%d): %s (log %s)" % (os.path.basename(str(cmd[0])), r.returncode,
                                                           " / ".join(tail), log))
    with open(log) as f:
        return f.read()


def visual_groups(run_dir, run):
    """key -> the label of its visual group: the pieces (pieces.csv) that accepted visual loops
    (loops.csv, which holds no nav placement) tie together, within one map."""
    piece = lambda key: run.pieces.get(key, str(key[0]))
    parent = {}

    def find(x):
        parent.setdefault(x, x)
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for key in run.slam.poses:
        find(piece(key))
    loops = os.path.join(run_dir, "loops.csv")
    for l in read_csv(loops) if os.path.exists(loops) else []:
        a, b = (int(l["session_a"]), int(l["index_a"])), (int(l["session_b"]), int(l["index_b"]))
        if a in run.slam.poses and b in run.slam.poses:
            parent[find(piece(a))] = find(piece(b))
    # A group never spans two maps (a loop between maps is not joined yet): label by map too.
    return {key: "%s/%s" % (run.slam.frame[key], find(piece(key))) for key in run.slam.poses}


def scored(run, gt, frames, blind):
    """(RMS error of the keyframes that see the seabed, RMS error of the blind ones), each keyframe in
    its frame (frames: key -> frame id) as evaluate.py puts the ground truth in a map's frame (at
    the frame's first keyframe: lowest session, then index). A frame whose first keyframe is not its
    map's (a visual group the nav placed in a map) has its poses taken relative to that keyframe:
    scored in its own frame, not where the map put it."""
    anchors, map_anchors = {}, {}
    for key in sorted(run.slam.poses):
        anchors.setdefault(frames[key], key)
        map_anchors.setdefault(run.slam.frame[key], key)
    poses = {}
    for k, p in run.slam.poses.items():
        anchor = anchors[frames[k]]
        poses[k] = p if anchor == map_anchors[run.slam.frame[k]] else evaluate.relative(run.slam.poses[anchor], p)
    truth, _ = evaluate.gt_in_estimate_frames(evaluate.Estimate("slam", poses, frames), gt)
    seen, dark = [], []
    for key, pose in poses.items():
        if key in truth:
            (dark if key in blind else seen).append(math.dist(pose[:2], truth[key][:2]))
    rms = lambda v: math.sqrt(sum(x * x for x in v) / len(v)) if v else None
    return rms(seen), rms(dark)


def ate(run_dir, sessions, world_gt, blind):
    """The map ATE of the table (its keyframes that see the seabed, and the blind ones), each keyframe
    in the frame of its visual group (visual_groups), through evaluate.py's own functions."""
    run = evaluate.load_run(run_dir)
    return scored(run, evaluate.load_ground_truth(sessions, world_gt), visual_groups(run_dir, run), blind)


def one_frame_ate(run_dir, sessions, world_gt, blind):
    """The same ATE with each keyframe in the frame of its map (nav placements included)."""
    run = evaluate.load_run(run_dir)
    return scored(run, evaluate.load_ground_truth(sessions, world_gt), run.slam.frame, blind)[0]


def placement_errors(run_dir, sessions, world_gt):
    """(error, sigma) in metres of each row of nav_placements.csv: its pose against the ground truth's
    relative pose of its two keyframes, and its sigma_xy_m."""
    path = os.path.join(run_dir, "nav_placements.csv")
    if not os.path.exists(path):
        return []
    gt = evaluate.load_ground_truth(sessions, world_gt)
    out = []
    for p in read_csv(path):
        truth = gt.relative((int(p["session_a"]), int(p["index_a"])), (int(p["session_b"]), int(p["index_b"])))
        out.append((math.dist((float(p["x_m"]), float(p["y_m"])), truth[:2]), float(p["sigma_xy_m"])))
    return out


def blind_frames(survey):
    """(session, index) of every frame inside a blank or occluded stretch."""
    out = set()
    for number, session in enumerate(survey["sessions"]):
        for st in (session.get("water") or {}).get("stretches") or []:
            out.update((number, i) for i in range(st["first_frame"], st["first_frame"] + st["num_frames"]))
    return out


def count(pattern, text):
    return sum(int(m) for m in re.findall(pattern, text))


def run_row(row, args, out):
    os.makedirs(out, exist_ok=True)
    spec_path = os.path.join(out, "survey.yaml")
    write_atomically(spec_path, yaml.safe_dump(row["survey"], sort_keys=False))
    mission = os.path.join(out, "mission")
    run([os.path.join(args.bin, "make_survey"), "--config", spec_path, "--out", mission, "--no-bag", "--quiet"],
        os.path.join(out, "make_survey.log"))
    sessions = [os.path.join(mission, s["name"]) for s in row["survey"]["sessions"]]
    result = {}
    for mode in ("on", "off"):
        run_dir = os.path.join(out, mode)
        cmd = [os.path.join(args.bin, "offline_slam")]
        for s in sessions:
            cmd += ["--session", s]
        cmd += ["--out", run_dir, "--nav", mode]
        if args.config:
            cmd += ["--config", args.config]
        log = run(cmd, os.path.join(out, "offline_slam_%s.log" % mode))
        report = os.path.join(run_dir, "report")
        ev = [sys.executable, os.path.join(REPO, "src", "tools", "evaluate.py"), "--run", run_dir, "--report", report,
              "--no-plots", "--world-gt", os.path.join(mission, "world_gt.csv"),
              "--loops-gt", os.path.join(mission, "loops_gt.csv")]
        for s in sessions:
            ev += ["--session", s]
        run(ev, os.path.join(out, "evaluate_%s.log" % mode))
        trajectory = read_csv(os.path.join(run_dir, "trajectory.csv"))
        world_gt, blind = os.path.join(mission, "world_gt.csv"), blind_frames(row["survey"])
        seen, dark = ate(run_dir, sessions, world_gt, blind)
        whole = one_frame_ate(run_dir, sessions, world_gt, blind)
        placements = placement_errors(run_dir, sessions, world_gt)
        result[mode] = {
            "ate": seen,
            "blind": dark,
            "whole": whole,
            "placements": placements,
            "pieces": len(read_csv(os.path.join(run_dir, "pieces.csv"))),
            "maps": len({t["map"] for t in trajectory}),
            "refused": len(read_csv(os.path.join(run_dir, "loops_refused.csv"))),
            "refused_on_arrival": len(re.findall(r"backend: loop \S+ -> \S+ refused:", log)),
            "carried": count(r"(\d+) frames carried by the nav", log),
            "implausible": count(r"(\d+) nav steps too fast", log),
            "fallbacks": count(r"(\d+) fallbacks", log),
            "trajectory": {(t["session"], t["index"]): (float(t["x_m"]), float(t["y_m"])) for t in trajectory},
        }
    return result


def mm(v):
    return "n/a" if v is None else "%.1f" % (v * 1000)


def placed(placements):
    """"n" or "n: worst error / its sigma (mm)" (worst by error over sigma)."""
    if not placements:
        return "0"
    error, sigma = max(placements, key=lambda p: p[0] / p[1])
    return "%d: %s / %s" % (len(placements), mm(error), mm(sigma))


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--bin", required=True, help="directory of make_survey and offline_slam")
    p.add_argument("--out", required=True, help="working directory (one folder per row)")
    p.add_argument("--spec", default=os.path.join(REPO, "test", "nav_bench.yaml"), help="the rows")
    p.add_argument("--rows", help="comma-separated row names (default: all)")
    p.add_argument("--config", help="an offline_slam --config for both runs")
    args = p.parse_args(argv)
    with open(args.spec) as f:
        rows = yaml.safe_load(f)["rows"]
    names = [r["name"] for r in rows]
    if args.rows:
        wanted = args.rows.split(",")
        unknown = [w for w in wanted if w not in names]
        if unknown:
            p.error("unknown rows %s (the rows: %s)" % (", ".join(unknown), ", ".join(names)))
        rows = [r for r in rows if r["name"] in wanted]
    results = {}
    print("| row | map ATE with nav (mm) | without nav (mm) | ratio | blind, with nav (mm) | one frame, with nav (mm) "
          "| pieces with / without | maps with / without | placed by nav: worst error / sigma (mm) "
          "| refused loops (on arrival) with / without | with nav: carried / implausible / fallbacks | rule |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    failed = 0
    for row in rows:
        t0 = time.time()
        try:
            r = results[row["name"]] = run_row(row, args, os.path.join(args.out, row["name"]))
        except RuntimeError as e:
            print("bench_nav: row %s: %s" % (row["name"], e), file=sys.stderr)
            return 2
        on, off = r["on"], r["off"]
        ok = on["ate"] is not None and off["ate"] is not None and on["ate"] <= off["ate"] + RULE_MARGIN_M
        failed += not ok
        ratio = "n/a" if not (on["ate"] and off["ate"]) else "%.2f" % (on["ate"] / off["ate"])
        print("| %s | %s | %s | %s | %s | %s | %d / %d | %d / %d | %s | %d (%d) / %d (%d) | %d / %d / %d | %s |" %
              (row["name"], mm(on["ate"]), mm(off["ate"]), ratio, mm(on["blind"]), mm(on["whole"]), on["pieces"],
               off["pieces"], on["maps"], off["maps"], placed(on["placements"]), on["refused"],
               on["refused_on_arrival"], off["refused"],
               off["refused_on_arrival"], on["carried"], on["implausible"], on["fallbacks"],
               "PASS" if ok else "FAIL"), flush=True)
        print("bench_nav: %s done in %.0f s" % (row["name"], time.time() - t0), file=sys.stderr, flush=True)
    print()
    for row in rows:
        twin = row.get("twin_of")
        if not twin or twin not in results:
            continue
        a, b = results[row["name"]]["on"]["trajectory"], results[twin]["on"]["trajectory"]
        common = set(a) & set(b)
        worst = max((math.dist(a[k], b[k]) for k in common), default=float("nan"))
        print("twin %s / %s (--nav on): %d keyframes in both, %d in one only, largest position difference %.3f mm" %
              (row["name"], twin, len(common), len(set(a) ^ set(b)), worst * 1000))
    print("%d of %d rows pass (with nav <= without nav + %.0f mm); runs in %s" %
          (len(rows) - failed, len(rows), RULE_MARGIN_M * 1000, args.out))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
