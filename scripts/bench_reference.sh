#!/usr/bin/env bash
# The offline reference: COLMAP (incremental SfM with bundle adjustment, what people use to reconstruct a
# survey offline) on the same frames as offline_slam, both scored by src/tools/evaluate.py, side by side:
# models (pieces), frames in a model, ATE after a similarity alignment (SfM has no metric scale; ours is
# aligned the same way, and its metric ATE is printed too), seconds.
#   COLMAP: CPU, one thread, COLMAP's SIFT capped at 2048 features per image (its default 8192 took 3 s per
#   pair to match on one core: 9 hours for the 10,878 pairs of 148 frames), exhaustive matching, one PINHOLE
#   camera with the dataset's intrinsics (camera.yaml) held fixed in bundle adjustment.
#   Each COLMAP model becomes a map of a run evaluate.py reads: the camera centres projected on the plane
#   that fits them (axes: the cameras' mean image u and v directions), yaw of the image u axis.
# A benchmark-only tool: COLMAP is installed here when missing (apt-get install colmap, Debian's 3.8;
# not in scripts/install_deps.sh). Minutes of CPU per 100 frames (exhaustive matching is quadratic).
# usage: scripts/bench_reference.sh DATASET [OUT_DIR]   (DATASET: a dataset folder with gt.csv; needs a build)
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
[ $# -ge 1 ] || { sed -n '2,12p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2; exit 2; }
dataset=$(cd "$1" && pwd -P)
out=${2:-$(mktemp -d /tmp/uwms_bench_reference.XXXXXX)}
mkdir -p "$out"
out=$(cd "$out" && pwd -P)
bin="$UWMS_WS/devel/lib/uw_multislam"
[ -x "$bin/offline_slam" ] || { echo "bench_reference: build first (scripts/build.sh)" >&2; exit 1; }
[ -f "$dataset/gt.csv" ] || { echo "bench_reference: $dataset has no gt.csv" >&2; exit 1; }
if ! command -v colmap > /dev/null; then
  echo "[bench_reference] installing COLMAP (apt-get install colmap)" >&2
  if [ "$(id -u)" = 0 ]; then apt-get install -y -q colmap >&2; else sudo apt-get install -y -q colmap >&2; fi
fi
evaluate="$UWMS_REPO/src/tools/evaluate.py"
eval_args=(--session "$dataset")
parent=$(dirname "$dataset")
[ -f "$parent/world_gt.csv" ] && eval_args+=(--world-gt "$parent/world_gt.csv")
[ -f "$parent/loops_gt.csv" ] && eval_args+=(--loops-gt "$parent/loops_gt.csv")
seconds() { echo "$(date +%s.%N) - $1" | bc -l; }

# --- ours -----------------------------------------------------------------------------------------------
t0=$(date +%s.%N)
"$bin/offline_slam" --session "$dataset" --out "$out/ours" --threads 1 > "$out/ours.log" 2>&1 ||
  { echo "bench_reference: offline_slam failed (see $out/ours.log)" >&2; exit 1; }
ours_s=$(seconds "$t0")
/usr/bin/python3 "$evaluate" --run "$out/ours" "${eval_args[@]}" --report "$out/ours/report" --no-plots > /dev/null

# --- COLMAP ---------------------------------------------------------------------------------------------
c="$out/colmap"
rm -rf "$c" && mkdir -p "$c/sparse"
tail -n +2 "$dataset/frames.csv" | cut -d, -f2 > "$c/images.txt"
# COLMAP keeps no model under 10 images: a shorter sequence (acfr: 8-9 frames, of which 8 registered) made none; 3 there.
frames=$(($(wc -l < "$dataset/frames.csv") - 1))
min_model=$((frames < 10 ? 3 : 10))
params=$(awk -F': *' '$1=="fx"{fx=$2} $1=="fy"{fy=$2} $1=="cx"{cx=$2} $1=="cy"{cy=$2} END {print fx "," fy "," cx "," cy}' \
  "$dataset/camera.yaml")
t0=$(date +%s.%N)
{
  colmap feature_extractor --database_path "$c/db.db" --image_path "$dataset" --image_list_path "$c/images.txt" \
    --ImageReader.camera_model PINHOLE --ImageReader.single_camera 1 --ImageReader.camera_params "$params" \
    --SiftExtraction.use_gpu 0 --SiftExtraction.num_threads 1 --SiftExtraction.max_num_features 2048
  colmap exhaustive_matcher --database_path "$c/db.db" --SiftMatching.use_gpu 0 --SiftMatching.num_threads 1
  colmap mapper --database_path "$c/db.db" --image_path "$dataset" --output_path "$c/sparse" --Mapper.num_threads 1 \
    --Mapper.min_model_size "$min_model" \
    --Mapper.ba_refine_focal_length 0 --Mapper.ba_refine_principal_point 0 --Mapper.ba_refine_extra_params 0
} > "$c/colmap.log" 2>&1 || { echo "bench_reference: COLMAP failed (see $c/colmap.log)" >&2; exit 1; }
colmap_s=$(seconds "$t0")
for m in "$c"/sparse/*/; do
  colmap model_converter --input_path "$m" --output_path "$m" --output_type TXT >> "$c/colmap.log" 2>&1
done

# COLMAP's models as a run of evaluate.py: map = model number.
/usr/bin/python3 - "$dataset" "$c" <<'PY'
import csv, glob, math, os, sys
import numpy as np
dataset, c = sys.argv[1], sys.argv[2]
index_of = {r["image"]: int(r["index"]) for r in csv.DictReader(open(os.path.join(dataset, "frames.csv")))}
rows = []
for m, model in enumerate(sorted(glob.glob(os.path.join(c, "sparse", "*", "images.txt")))):
    centres, xaxes, zaxes, keys = [], [], [], []
    lines = [l for l in open(model) if not l.startswith("#")]
    for line in lines[0::2]:  # each image: a pose line, then a line of its 2-D points
        f = line.split()
        if len(f) < 10:
            continue
        qw, qx, qy, qz, tx, ty, tz = map(float, f[1:8])
        R = np.array([[1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
                      [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
                      [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)]])
        centres.append(-R.T @ np.array([tx, ty, tz]))  # world to camera: the centre is -R^T t
        xaxes.append(R.T[:, 0])
        zaxes.append(R.T[:, 2])
        keys.append(index_of[f[9]])
    if not keys:
        continue
    n = np.mean(zaxes, axis=0)
    n /= np.linalg.norm(n)  # the mean viewing direction: the seabed's normal, away from the cameras
    e1 = np.mean(xaxes, axis=0)
    e1 -= n * (e1 @ n)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)  # image v for a camera looking along n with u along e1
    o = centres[0]
    for k, C, x in zip(keys, centres, xaxes):
        rows.append((k, m, (C - o) @ e1, (C - o) @ e2, math.atan2(x @ e2, x @ e1)))
rows.sort()
os.makedirs(os.path.join(c, "run"), exist_ok=True)
with open(os.path.join(c, "run", "trajectory.csv"), "w") as t, open(os.path.join(c, "run", "odometry.csv"), "w") as o:
    t.write("session,index,map,x_m,y_m,yaw_rad\n")
    o.write("session,index,x_m,y_m,yaw_rad\n")
    for k, m, x, y, yaw in rows:
        t.write("0,%d,%d,%.6f,%.6f,%.7f\n" % (k, m, x, y, yaw))
        o.write("0,%d,%.6f,%.6f,%.7f\n" % (k, x, y, yaw))
PY
/usr/bin/python3 "$evaluate" --run "$c/run" "${eval_args[@]}" --report "$c/run/report" --no-plots > /dev/null

# --- side by side ---------------------------------------------------------------------------------------
# row NAME RUN SECONDS: models, frames in models, largest model's frames, ATE (similarity, each model aligned
# alone; frames weighted), metric ATE of the largest map.
row() {
  /usr/bin/python3 - "$2/report/metrics.json" "$2/trajectory.csv" "$1" "$3" <<'PY'
import csv, json, sys
metrics, traj, name, secs = json.load(open(sys.argv[1])), sys.argv[2], sys.argv[3], float(sys.argv[4])
maps = metrics.get("map", {})
sizes = {m: v["slam"]["n_keyframes"] for m, v in maps.items()}
frames = sum(sizes.values())
sim = [(v["slam"]["ate_sim_rmse_m"], v["slam"]["n_keyframes"]) for v in maps.values() if v["slam"]["ate_sim_rmse_m"] is not None]
ate_sim = (sum(a * a * n for a, n in sim) / sum(n for _, n in sim)) ** 0.5 if sim else float("nan")
largest = max(sizes, key=sizes.get)
metric = maps[largest]["slam"]["ate_rmse_m"]
print("| %s | %d | %d | %d | %.3f | %s | %.1f |" % (name, len(maps), frames, sizes[largest], ate_sim,
      "%.3f" % metric if metric is not None and name.startswith("ours") else "n/a (no scale)", secs))
PY
}
echo "### $(basename "$(dirname "$dataset")")/$(basename "$dataset") ($frames frames): ours against COLMAP $(colmap -h 2>&1 | sed -n 's/^COLMAP \([0-9.]*\).*/\1/p'), one core"
echo
echo "| method | models (pieces) | frames in a model | frames in the largest | ATE after similarity alignment (m) | metric ATE, largest (m) | seconds |"
echo "|---|---|---|---|---|---|---|"
row "ours (offline_slam, keyframes)" "$out/ours" "$ours_s"
row "COLMAP (exhaustive, fixed intrinsics)" "$c/run" "$colmap_s"
echo
echo "runs in $out"
