#!/usr/bin/env bash
# Odometry benchmark on real water: our offline_slam odometry against the naive OpenCV
# baseline (baseline_odometry) on ../shared/data/acfr/test1..test6, both scored by evaluate.py
# against the navigation ground truth. Prints one markdown table (end drift % of path, ATE).
# usage: scripts/bench_odometry.sh [--config FILE] [OUT_DIR]   (needs a build: scripts/build.sh)
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
config_args=()
if [ "${1:-}" = "--config" ]; then config_args=(--config "$2"); shift 2; fi
out=${1:-$(mktemp -d /tmp/uwms_bench_odometry.XXXXXX)}
mkdir -p "$out"
data="$UWMS_REPO/../shared/data/acfr"
bin="$UWMS_WS/devel/lib/uw_multislam"
[ -d "$data" ] || { echo "bench_odometry: $data not found (the shared data sits beside the repository)" >&2; exit 1; }
[ -x "$bin/offline_slam" ] || { echo "bench_odometry: build first (scripts/build.sh)" >&2; exit 1; }

metric() {  # metric REPORT_DIR NAME -> value of session 0 odometry
  awk -F, -v m="$2" '$1=="session" && $2=="0" && $3=="odometry" && $4==m {printf "%.3f", $5}' "$1/metrics.csv"
}
echo "| sequence | ours drift % | baseline drift % | ours ATE m | baseline ATE m | ours fallbacks |"
echo "|---|---|---|---|---|---|"
sum_o=0; sum_b=0; wins=0; n=0
for seq in "$data"/test*; do
  name=$(basename "$seq")
  "$bin/offline_slam" --session "$seq" --out "$out/ours_$name" "${config_args[@]}" > "$out/ours_$name.log" 2>&1
  "$bin/baseline_odometry" --session "$seq" --out "$out/base_$name" > "$out/base_$name.log" 2>&1
  for r in ours base; do
    /usr/bin/python3 "$UWMS_REPO/src/tools/evaluate.py" --run "$out/${r}_$name" --session "$seq" \
      --report "$out/${r}_$name/report" --no-plots > /dev/null
  done
  do_=$(metric "$out/ours_$name/report" end_drift_pct); db=$(metric "$out/base_$name/report" end_drift_pct)
  ao=$(metric "$out/ours_$name/report" ate_rmse_m); ab=$(metric "$out/base_$name/report" ate_rmse_m)
  fb=$(sed -n 's/.* \([0-9]*\) fallbacks.*/\1/p' "$out/ours_$name.log")
  echo "| $name | $do_ | $db | $ao | $ab | $fb |"
  sum_o=$(echo "$sum_o + $do_" | bc -l); sum_b=$(echo "$sum_b + $db" | bc -l); n=$((n + 1))
  if [ "$(echo "$do_ < $db" | bc -l)" = 1 ]; then wins=$((wins + 1)); fi
done
printf "| mean | %.3f | %.3f | | | |\n" "$(echo "$sum_o / $n" | bc -l)" "$(echo "$sum_b / $n" | bc -l)"
echo "ours better on $wins of $n sequences; runs in $out"

# Speed: ms per frame per stage on one core (offline_slam --threads 1), at 320x240 on a
# generated textured mission and at 680x512 on the ACFR frames.
"$UWMS_WS/devel/lib/uw_multislam/make_survey" --preset textured --out "$out/textured" --no-bag --quiet > /dev/null
"$bin/offline_slam" --session "$out/textured/s0" --out "$out/speed_320" --threads 1 "${config_args[@]}" > /dev/null 2>&1
acfr_sessions=()
for seq in "$data"/test*; do acfr_sessions+=(--session "$seq"); done
"$bin/offline_slam" "${acfr_sessions[@]}" --out "$out/speed_680" --threads 1 "${config_args[@]}" > /dev/null 2>&1
echo
echo "| stage (mean ms per call, 1 core) | 320x240 | 680x512 |"
echo "|---|---|---|"
for stage in load_image enhance features match ransac odometry_total; do
  a=$(awk -F, -v s=$stage '$1==s {printf "%.1f", $4}' "$out/speed_320/timing.csv")
  b=$(awk -F, -v s=$stage '$1==s {printf "%.1f", $4}' "$out/speed_680/timing.csv")
  echo "| $stage | $a | $b |"
done
