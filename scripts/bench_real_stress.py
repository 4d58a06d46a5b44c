#!/usr/bin/python3
"""The odometry's stress bench on the shared real frames (doc/benchmarks/real_survey.md).

Each base sequence (../shared/data/skerki_survey/s0, ../shared/data/acfr/test1-6) is run by
offline_slam (one core, --threads 1) as it is and as variant folders made in a temporary
directory (image hard links or copies, frames.csv, gt.csv and the loops' ground truth filtered):
  all      every frame
  every2   every 2nd frame          every3   every 3rd frame
  every2k  every 2nd frame, and the frames on both sides of each of the recording's own gaps (a
           stamp step over 1.5 times the median): no step spans a recorded gap and a dropped frame
  gaps0.9  runs of frames removed to make ~0.9 m steps: after every 5 kept frames the frame
           whose ground-truth distance from the last kept one is closest to 0.9 m is kept next
           (what a pause or a stalled camera gives)
For each it prints the tracking losses, pieces, maps, frames kept (frames inside a piece), the
wrong loops (evaluate.py), each bridge's error (a frame left unmatched inside a piece: the
keyframe step across it against the ground truth), and beside it the consecutive pairs a careful
registration accepts, made here and not in the product: the pseudo ground truth's registration
(../shared/data/skerki_survey/README.md): flat-field normalisation (image / Gaussian blur, sigma
40 px, stretched between its 0.5 and 99.5 percentiles), RootSIFT with contrastThreshold 0.01, mutual nearest neighbours with ratio < 0.9, a
similarity by RANSAC at 3 px, accepted with >= 40 inliers, inlier RMS < 2.5 px, scale in
(0.85, 1.18) (">= 20" counts the pairs with 20 inliers or more). "losses where registered" counts
the tracking losses whose breaking pair (the piece's last frame and the next frame of the
variant) that registration accepts: the target is none.

usage: scripts/bench_real_stress.py [--config FILE] [--only NAME ...] [--out DIR] [--registration-cache CSV]
  NAME: a row name (skerki_s0_every2, acfr_test3_all, ...) or a prefix (skerki_s0, acfr).
Needs a build (scripts/build.sh) and Debian's python3-opencv. About 6 minutes on one idle core.
"""
import argparse
import csv
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time

try:
    import cv2
    import numpy as np
except ImportError as e:  # the careful registration needs them; the variants and runs do not (the tests)
    cv2 = np = None
    MISSING = e

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.path.join(REPO, "..", "shared", "data")
WS = os.environ.get("UWMS_WS") or os.path.join(os.path.dirname(REPO), os.path.basename(REPO) + "_ws")
BIN = os.path.join(WS, "devel", "lib", "uw_multislam")


def read_csv(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def write_csv(path, fields, rows):
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields)
        w.writeheader()
        w.writerows(rows)


# ---- the variants ----------------------------------------------------------------------------

def gap_selection(gt, keep_run=5, step_m=0.9):
    """Indexes into gt (rows in order): runs of keep_run frames, then a step of ~step_m."""
    pos = [(float(r["x_m"]), float(r["y_m"])) for r in gt]
    chosen, i, run = [0], 0, 1
    while i < len(gt) - 1:
        if run < keep_run:
            i += 1
            run += 1
        else:
            j, best = i + 1, i + 1
            while j < len(gt):
                d = math.dist(pos[i], pos[j])
                if abs(d - step_m) < abs(math.dist(pos[i], pos[best]) - step_m):
                    best = j
                if d > step_m:
                    break
                j += 1
            i, run = best, 1
        chosen.append(i)
    return chosen


def frames_before_gaps(frames, factor=1.5):
    """Indexes into frames (rows in order) of the frames followed by a stamp step over `factor`
    times the median step: the recording's own gaps (skerki s0 has three of 22 s among 13 s steps)."""
    stamps = [float(r["stamp_s"]) for r in frames]
    steps = [b - a for a, b in zip(stamps, stamps[1:])]
    if not steps:
        return []
    median = sorted(steps)[len(steps) // 2]
    return [k for k, step in enumerate(steps) if step > factor * median]


def place(src, dst):
    """src at dst: a hard link, or a copy across file systems. Not a symlink: offline_slam refuses
    an image whose real path leaves the dataset folder."""
    if os.path.lexists(dst):
        return
    try:
        os.link(src, dst)
    except OSError:
        shutil.copyfile(src, dst)


def make_variant(base_dir, name, out_dir, loops_dir=None):
    frames = read_csv(os.path.join(base_dir, "frames.csv"))
    gt = read_csv(os.path.join(base_dir, "gt.csv"))
    if name == "all":
        keep = list(range(len(frames)))
    elif name == "every2k":
        keep = sorted(set(range(0, len(frames), 2)) | {k + d for k in frames_before_gaps(frames) for d in (0, 1)})
    elif name.startswith("every"):
        keep = list(range(0, len(frames), int(name[5:])))
    else:
        keep = gap_selection(gt)
    d = os.path.join(out_dir, os.path.basename(base_dir.rstrip("/")) + "_" + name)
    os.makedirs(d, exist_ok=True)
    for name_in_dir in [frames[k]["image"] for k in keep] + ["camera.yaml"]:
        place(os.path.join(base_dir, name_in_dir), os.path.join(d, name_in_dir))
    write_csv(os.path.join(d, "frames.csv"), list(frames[0].keys()), [frames[k] for k in keep])
    write_csv(os.path.join(d, "gt.csv"), list(gt[0].keys()), [gt[k] for k in keep])
    kept = {int(frames[k]["index"]) for k in keep}
    extra = {}
    if loops_dir:
        for f, keys in (("loops_gt.csv", ("index_a", "index_b")), ("world_gt.csv", ("index",))):
            rows = read_csv(os.path.join(loops_dir, f))
            write_csv(os.path.join(d, f), list(rows[0].keys()), [r for r in rows if all(int(r[k]) in kept for k in keys)])
        extra = {"world_gt": os.path.join(d, "world_gt.csv"), "loops_gt": os.path.join(d, "loops_gt.csv")}
    return d, extra


# ---- the careful registration (the reference, not the product) --------------------------------

class Registration:
    def __init__(self, cache_file):
        if cv2 is None:  # a message rather than a trace
            sys.exit("bench_real_stress: %s (apt-get install python3-opencv)" % MISSING)
        self.sift = cv2.SIFT_create(contrastThreshold=0.01)
        self.cache = {}  # image realpath -> (points, RootSIFT descriptors)
        self.pairs = {}  # (realpath a, realpath b) -> (inliers, accepted)
        self.cache_file = cache_file
        if cache_file and os.path.exists(cache_file):
            for r in read_csv(cache_file):
                self.pairs[(r["a"], r["b"])] = (int(r["inliers"]), r["accepted"] == "1")

    def save(self):
        if self.cache_file:
            write_csv(self.cache_file, ["a", "b", "inliers", "accepted"],
                      [{"a": a, "b": b, "inliers": n, "accepted": int(ok)} for (a, b), (n, ok) in self.pairs.items()])

    def features(self, path):
        key = os.path.realpath(path)
        if key not in self.cache:
            grey = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
            if grey is None:
                sys.exit("bench_real_stress: cannot read %s" % path)
            g = grey.astype(np.float32) + 1.0
            ratio = g / cv2.GaussianBlur(g, (0, 0), 40)
            # Stretched between its 0.5 and 99.5 percentiles: a min-max stretch lets a few specular
            # pixels squash the rest (900 instead of 3000 keypoints on skerki s0).
            lo, hi = np.percentile(ratio, [0.5, 99.5])
            flat = np.clip((ratio - lo) * (255.0 / max(hi - lo, 1e-6)), 0, 255).astype(np.uint8)
            kps, d = self.sift.detectAndCompute(flat, None)
            if d is None:
                self.cache[key] = (np.zeros((0, 2), np.float32), np.zeros((0, 128), np.float32))
            else:
                d = d / (np.abs(d).sum(axis=1, keepdims=True) + 1e-7)  # RootSIFT: L1-normalised, square root
                self.cache[key] = (np.float32([k.pt for k in kps]), np.sqrt(d).astype(np.float32))
        return self.cache[key]

    def register(self, path_a, path_b):
        key = (os.path.realpath(path_a), os.path.realpath(path_b))
        if key not in self.pairs:
            self.pairs[key] = self._register(path_a, path_b)
        return self.pairs[key]

    def _register(self, path_a, path_b):
        pa, da = self.features(path_a)
        pb, db = self.features(path_b)
        if len(pa) < 3 or len(pb) < 3:
            return 0, False
        # Mutual nearest neighbours with the ratio test, from one distance table (numpy's matrix
        # product: as cv2.BFMatcher's knnMatch both ways, several times faster on 4000 x 4000).
        d2 = (da * da).sum(1)[:, None] + (db * db).sum(1)[None, :] - 2.0 * da @ db.T
        two = np.argpartition(d2, 1, axis=1)[:, :2]
        rows = np.arange(len(da))
        first = np.where(d2[rows, two[:, 0]] <= d2[rows, two[:, 1]], two[:, 0], two[:, 1])
        second = np.where(first == two[:, 0], two[:, 1], two[:, 0])
        d1, dn = np.sqrt(np.maximum(d2[rows, first], 0)), np.sqrt(np.maximum(d2[rows, second], 0))
        mutual = np.argmin(d2, axis=0)[first] == rows
        pairs = [(int(i), int(first[i])) for i in np.nonzero((d1 < 0.9 * dn) & mutual)[0]]
        if len(pairs) < 3:
            return 0, False
        src = np.float32([pb[j] for _, j in pairs])
        dst = np.float32([pa[i] for i, _ in pairs])
        model, mask = cv2.estimateAffinePartial2D(src, dst, method=cv2.RANSAC, ransacReprojThreshold=3.0,
                                                  maxIters=5000, confidence=0.999)
        if model is None:
            return 0, False
        inl = mask.ravel().astype(bool)
        n = int(inl.sum())
        residual = (src[inl] @ model[:, :2].T + model[:, 2]) - dst[inl]
        rms = float(np.sqrt((residual ** 2).sum(axis=1).mean())) if n else 0.0
        scale = float(np.hypot(model[0, 0], model[1, 0]))
        return n, n >= 40 and rms < 2.5 and 0.85 < scale < 1.18


# ---- one run ---------------------------------------------------------------------------------

def relative(p, q):
    """q in p's frame: (x, y, yaw)."""
    dx, dy = q[0] - p[0], q[1] - p[1]
    c, s = math.cos(p[2]), math.sin(p[2])
    return c * dx + s * dy, -s * dx + c * dy, math.remainder(q[2] - p[2], 2 * math.pi)


def run_one(name, folder, extra, out, config, reg):
    """offline_slam and evaluate.py on one variant folder, and what the table prints; reg: the
    careful registration, or None (its columns then count nothing)."""
    run_dir = os.path.join(out, "runs", name)
    cmd = [os.path.join(BIN, "offline_slam"), "--session", folder, "--out", run_dir, "--threads", "1"]
    if config:
        cmd += ["--config", config]
    tc0 = os.times()
    with open(run_dir + ".log", "w") as log:
        if subprocess.call(cmd, stdout=log, stderr=subprocess.STDOUT) != 0:
            sys.exit("bench_real_stress: offline_slam failed on %s (see %s.log)" % (folder, run_dir))
    tc1 = os.times()
    cpu_s = (tc1.children_user - tc0.children_user) + (tc1.children_system - tc0.children_system)
    ev = [sys.executable, os.path.join(REPO, "src", "tools", "evaluate.py"), "--run", run_dir, "--session", folder,
          "--report", os.path.join(run_dir, "report"), "--no-plots"]
    if extra:
        ev += ["--world-gt", extra["world_gt"], "--loops-gt", extra["loops_gt"]]
    with open(run_dir + ".eval", "w") as log:
        if subprocess.call(ev, stdout=log, stderr=subprocess.STDOUT) != 0:
            sys.exit("bench_real_stress: evaluate.py failed on %s (see %s.eval)" % (name, run_dir))
    frames = read_csv(os.path.join(folder, "frames.csv"))
    order = [int(r["index"]) for r in frames]
    image = {int(r["index"]): os.path.join(folder, r["image"]) for r in frames}
    gt = {int(r["index"]): (float(r["x_m"]), float(r["y_m"]), float(r["yaw_rad"]))
          for r in read_csv(os.path.join(folder, "gt.csv"))}
    pieces = read_csv(os.path.join(run_dir, "pieces.csv"))
    spans = sorted((int(p["first_index"]), int(p["last_index"])) for p in pieces)
    kept = sum(1 for i in order if any(a <= i <= b for a, b in spans))
    maps = len({r["map"] for r in read_csv(os.path.join(run_dir, "trajectory.csv"))})
    metrics = read_csv(os.path.join(run_dir, "report", "metrics.csv"))

    def metric(scope, ident, estimate, m):
        for r in metrics:
            if (r["scope"], r["id"], r["estimate"], r["metric"]) == (scope, ident, estimate, m):
                return r["value"]
        return "n/a"

    accepted, correct = metric("loops", "all", "loops", "accepted"), metric("loops", "all", "loops", "correct")
    wrong = "n/a" if "n/a" in (accepted, correct) else str(int(float(accepted)) - int(float(correct)))
    # Tracking losses: a piece's last frame and the variant's next frame.
    losses = []
    for (a0, a1), (b0, _) in zip(spans, spans[1:]):
        nxt = order[order.index(a1) + 1] if order.index(a1) + 1 < len(order) else None
        registered = nxt is not None and reg is not None and reg.register(image[a1], image[nxt])[1]
        losses.append((a1, nxt, b0, registered))
    # Bridges: frames left unmatched inside a piece, the keyframe step across each against the ground truth.
    bridged = set()
    with open(run_dir + ".log") as log:
        for line in log:
            if "odometry fallback (unmatched, bridged" in line:
                bridged.add(int(line.split(" frame ")[1].split(":")[0]))
    odo = {}
    for r in read_csv(os.path.join(run_dir, "odometry.csv")):
        odo[int(r["index"])] = (float(r["x_m"]), float(r["y_m"]), float(r["yaw_rad"]))
    keys = sorted(odo)
    bridge_errors = []
    for f in sorted(bridged):
        before = [k for k in keys if k < f]
        after = [k for k in keys if k > f]
        if not before or not after or not any(a <= before[-1] and after[0] <= b for a, b in spans):
            continue  # not inside one piece: the loss's, not a bridge
        e = relative(odo[before[-1]], odo[after[0]])
        g = relative(gt[before[-1]], gt[after[0]])
        bridge_errors.append((f, math.hypot(e[0] - g[0], e[1] - g[1])))
    # The worst odometry step between consecutive keyframes of one piece against the ground truth's:
    # a wrong registration (dense or not) shows here as a kink.
    worst_step = 0.0
    for a, b in zip(keys, keys[1:]):
        if any(lo <= a and b <= hi for lo, hi in spans):
            e, g = relative(odo[a], odo[b]), relative(gt[a], gt[b])
            worst_step = max(worst_step, math.hypot(e[0] - g[0], e[1] - g[1]))
    pairs = list(zip(order, order[1:]))
    regs = [reg.register(image[a], image[b]) for a, b in pairs] if reg is not None else []
    timing = {r["stage"]: r for r in read_csv(os.path.join(run_dir, "timing.csv"))}
    odo_ms = float(timing["odometry_total"]["mean_ms"]) if "odometry_total" in timing else float("nan")
    return {
        "name": name, "frames": len(order), "losses": len(losses), "pieces": len(spans), "maps": maps,
        "kept": kept, "wrong": wrong, "bridges": bridge_errors,
        "losses_registered": sum(1 for x in losses if x[3]), "loss_pairs": losses,
        "pairs": len(pairs), "reg_accepted": sum(1 for _, ok in regs if ok), "reg_20": sum(1 for n, _ in regs if n >= 20),
        "odometry_ms": odo_ms, "cpu_s": cpu_s, "worst_step": worst_step,
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", help="offline_slam --config FILE for every run")
    ap.add_argument("--only", nargs="*", default=[], help="rows (or prefixes of row names) to run")
    ap.add_argument("--out", help="where the variants and runs go (default: a new temporary directory)")
    ap.add_argument("--registration-cache", metavar="CSV",
                    help="the registration's results by image pair, read and extended (it depends on the images only)")
    args = ap.parse_args()
    if not os.path.isdir(os.path.join(DATA, "skerki_survey", "s0")) or not os.path.isdir(os.path.join(DATA, "acfr")):
        sys.exit("bench_real_stress: %s/skerki_survey/s0 or %s/acfr not found (the shared data beside the repository)"
                 % (DATA, DATA))
    if not os.access(os.path.join(BIN, "offline_slam"), os.X_OK):
        sys.exit("bench_real_stress: %s/offline_slam missing: build first (scripts/build.sh)" % BIN)
    out = args.out or tempfile.mkdtemp(prefix="uwms_bench_stress.")
    os.makedirs(os.path.join(out, "runs"), exist_ok=True)
    bases = [("skerki_s0", os.path.join(DATA, "skerki_survey", "s0"), os.path.join(DATA, "skerki_survey"))]
    bases += [("acfr_" + t, os.path.join(DATA, "acfr", t), None)
              for t in sorted(os.listdir(os.path.join(DATA, "acfr"))) if t.startswith("test")]
    reg = Registration(args.registration_cache)
    print("### Stress bench on real frames: %s, %s" % (
        time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        subprocess.run(["sh", "-c", "grep -m1 'model name' /proc/cpuinfo | cut -d: -f2"], capture_output=True,
                       text=True).stdout.strip()))
    print()
    print("| run | frames | tracking losses | pieces | maps | frames kept | wrong loops | bridges: count, "
          "largest error (m) | worst keyframe step error (m) | consecutive pairs | registration accepts (>= 40) / "
          ">= 20 | losses where registered | odometry ms/frame | CPU s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    results = []
    for base, folder, loops_dir in bases:
        for variant in ("all", "every2", "every2k", "every3", "gaps0.9"):
            name = base + "_" + variant
            if args.only and not any(name.startswith(o) for o in args.only):
                continue
            if variant == "every2k" and not frames_before_gaps(read_csv(os.path.join(folder, "frames.csv"))):
                continue  # no recorded gap: the same frames as every2
            d, extra = make_variant(folder, variant, os.path.join(out, "data"), loops_dir)
            r = run_one(name, d, extra, out, args.config, reg)
            results.append(r)
            reg.save()
            b = r["bridges"]
            print("| %s | %d | %d | %d | %d | %d (%.0f %%) | %s | %s | %.3f | %d | %d / %d | %d | %.1f | %.1f |" % (
                name, r["frames"], r["losses"], r["pieces"], r["maps"], r["kept"], 100.0 * r["kept"] / r["frames"],
                r["wrong"], "%d, %.3f" % (len(b), max(e for _, e in b)) if b else "0", r["worst_step"], r["pairs"],
                r["reg_accepted"], r["reg_20"], r["losses_registered"], r["odometry_ms"], r["cpu_s"]), flush=True)
    print()
    for r in results:
        for last, nxt, restart, registered in r["loss_pairs"]:
            print("- %s: tracking lost after frame %d (next frame %s, the registration %s the pair); the next piece "
                  "starts at frame %d" % (r["name"], last, nxt, "accepts" if registered else "refuses", restart))
        for f, e in r["bridges"]:
            print("- %s: frame %d bridged, the keyframe step across it %.3f m from the ground truth's" % (r["name"], f, e))
    print()
    print("runs in %s" % out)


if __name__ == "__main__":
    main()
