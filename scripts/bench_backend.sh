#!/usr/bin/env bash
# Back-end benchmark, four tables:
#   1. accuracy: offline_slam on generated missions with one, two and three sessions, the IEKF
#      and the sparse optimiser side by side (ATE, the paper's e_k before and after, joins);
#   2. cost: time and peak memory per optimiser at 100, 1k and 10k keyframes (bench_backend --cost);
#   3. robustness, the paper's Table 3 (bench_backend --robustness), with RUNS runs per level;
#   4. wrong loops, 0-50 % between sessions, both join policies (bench_backend --outliers).
# usage: scripts/bench_backend.sh [OUT_DIR]   env RUNS (default 20), SKIP_ROBUSTNESS=1, OUTLIER_RUNS (default 5)
# Needs a build (scripts/build.sh). Takes about 15 minutes on one core.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
out=${1:-$(mktemp -d /tmp/uwms_bench_backend.XXXXXX)}
mkdir -p "$out"
bin="$UWMS_WS/devel/lib/uw_multislam"
[ -x "$bin/bench_backend" ] || { echo "bench_backend: build first (scripts/build.sh)" >&2; exit 1; }
echo "# back-end benchmark, $(date -u +%F), $(uname -m), $(nproc) cores ($(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs))"

[ -d "$out/m3" ] || "$bin/make_survey" --config "$UWMS_REPO/config/missions/three_sessions.yaml" --out "$out/m3" --no-bag --quiet
if [ ! -d "$out/m1" ]; then  # the loop session alone (it has revisits within itself)
  /usr/bin/python3 -c 'import sys, yaml; c = yaml.safe_load(open(sys.argv[1])); c["sessions"] = c["sessions"][1:2]; print(yaml.safe_dump(c, sort_keys=False))' \
    "$UWMS_REPO/config/missions/three_sessions.yaml" > "$out/one_session.yaml"
  "$bin/make_survey" --config "$out/one_session.yaml" --out "$out/m1" --no-bag --quiet
fi
for opt in iekf sparse; do printf 'backend:\n  optimizer: %s\n' "$opt" > "$out/$opt.yaml"; done

echo; echo "## 1. Accuracy on generated missions (offline_slam, images rendered by make_survey)"; echo
echo "| sessions | optimiser | maps | session ATE odometry → SLAM (m) | map ATE (m) | e_k intra odometry → SLAM (m) | e_k inter (m) | back-end ms |"
echo "|---|---|---|---|---|---|---|---|"
run_case() {  # run_case LABEL OPT MISSION SESSION_DIRS...
  local label=$1 opt=$2 mission=$3; shift 3
  local args=() d
  for d in "$@"; do args+=(--session "$d"); done
  local o="$out/run_${label}_$opt"
  "$bin/offline_slam" "${args[@]}" --out "$o" --config "$out/$opt.yaml" --quiet > "$o.log" 2>&1 || { echo "offline_slam failed, see $o.log" >&2; exit 1; }
  # The mission folder holds world_gt.csv / loops_gt.csv; evaluate only the sessions given (evaluate.py refuses a
  # --mission with sessions the run does not have).
  local truth=() gt
  for d in "$@"; do truth+=(--session "$d"); done
  for gt in world_gt loops_gt; do [ -f "$mission/$gt.csv" ] && truth+=("--${gt/_/-}" "$mission/$gt.csv"); done
  /usr/bin/python3 "$UWMS_REPO/src/tools/evaluate.py" --run "$o" "${truth[@]}" --report "$o/report" --no-plots > /dev/null
  /usr/bin/python3 - "$o" "$label" "$opt" <<'PY'
import csv, sys, statistics as st
run, label, opt = sys.argv[1:]
m = {}
for r in csv.DictReader(open(run + "/report/metrics.csv")):
    m[(r["scope"], r["id"], r["estimate"], r["metric"])] = r["value"]
def f(k):
    v = m.get(k)
    return None if v in (None, "", "None", "nan", "n/a") else float(v)
sessions = sorted({k[1] for k in m if k[0] == "session"})
def mean(xs):
    xs = [x for x in xs if x is not None]
    return "%.3f" % st.mean(xs) if xs else "n/a"
ate_o = mean([f(("session", s, "odometry", "ate_rmse_m")) for s in sessions])
ate_s = mean([f(("map", mp, "slam", "ate_rmse_m")) for mp in sorted({k[1] for k in m if k[0] == "map"})])
ses_s = mean([f(("session", s, "slam", "ate_rmse_m")) for s in sessions])
ek_o = mean([f(("session", s, "odometry", "ek_intra_m")) for s in sessions])
ek_s = mean([f(("session", s, "slam", "ek_intra_m")) for s in sessions])
ek_i = mean([f(("map", mp, "slam", "ek_inter_m")) for mp in sorted({k[1] for k in m if k[0] == "map"})])
maps = len({k[1] for k in m if k[0] == "map"})
ms = sum(float(r["total_ms"]) for r in csv.DictReader(open(run + "/timing.csv")) if r["stage"] == "backend")
print("| %s | %s | %d | %s → %s | %s | %s → %s | %s | %.0f |" % (label, opt, maps, ate_o, ses_s, ate_s, ek_o, ek_s, ek_i, ms))
PY
}
for opt in iekf sparse; do run_case 1 "$opt" "$out/m1" "$out/m1/s1"; done
for opt in iekf sparse; do run_case 2 "$opt" "$out/m3" "$out/m3/s0" "$out/m3/s1"; done
for opt in iekf sparse; do run_case 3 "$opt" "$out/m3" "$out/m3/s0" "$out/m3/s1" "$out/m3/s2"; done

echo; echo "## 2. Cost (synthetic survey, one session, loops between neighbouring rows, one core)"; echo
echo "| optimiser | keyframes | loops | build ms | optimise all loops ms | one more loop ms | peak RSS MB | ATE m |"
echo "|---|---|---|---|---|---|---|---|"
for n in 100 1000 10000; do "$bin/bench_backend" --cost $n --loops $((n / 10)) --optimizer sparse; done
for n in 100 1000 2000; do "$bin/bench_backend" --cost $n --loops $((n / 10)) --optimizer iekf; done
echo "(iekf at 10k keyframes: its covariance alone is (3·10⁴)² doubles = 7.2 GB; not run)"

if [ "${SKIP_ROBUSTNESS:-0}" != 1 ]; then
  echo; echo "## 3. Robustness (the paper's Table 3) on the three-session mission"; echo
  "$bin/bench_backend" --robustness --mission "$out/m3" --runs "${RUNS:-20}"
fi

# 4. Wrong loops (the join policies' robustness): the two-session demo mission's true loops plus 0-50 % wrong ones
# between sessions, both join policies (bench_backend --outliers).
echo; echo "## 4. Wrong loops on the demo mission (bench_backend --outliers)"; echo
[ -d "$out/demo" ] || "$bin/make_survey" --preset demo --out "$out/demo" --no-bag --quiet
"$bin/bench_backend" --outliers 0,10,30,50 --mission "$out/demo" --runs "${OUTLIER_RUNS:-5}"
