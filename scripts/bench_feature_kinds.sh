#!/usr/bin/env bash
# SIFT against ORB (odometry.features.type) over many generated missions, not the one demo: the
# front-end table's recall column rests on 15 to 23 keyframe pairs of one mission, too few to
# choose a default by. For each built-in preset with sessions to join or haze to survive (demo: two
# sessions a day apart, the second dimmer and bluer; textured: one session over a textured seabed;
# hazy: turbid water) and each seed, both kinds run through offline_slam (one core) and are scored
# by evaluate.py against the mission's ground truth. One markdown table, a row per mission and kind:
# global (inter-session) and local (intra-session) loop pairs found of the keyframe pairs that
# overlap, precision, the number of maps at the end (more than the sessions: tracking was lost),
# map 0's keyframe ATE; then the sums per preset and kind.
# usage: scripts/bench_feature_kinds.sh [OUT_DIR] [--seeds "2 3 4 5"]   (needs a build; about 6 min)
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
out="" seeds="2 3 4 5"
while [ $# -gt 0 ]; do
  case "$1" in
    --seeds) seeds=$2; shift 2;;
    -h|--help) sed -n '2,11p' "$0"; exit 0;;
    *) out=$1; shift;;
  esac
done
out=${out:-$(mktemp -d /tmp/uwms_bench_feature_kinds.XXXXXX)}
mkdir -p "$out"
bin="$UWMS_WS/devel/lib/uw_multislam"
for t in offline_slam make_survey; do
  [ -x "$bin/$t" ] || { echo "bench_feature_kinds: $bin/$t missing: build first (scripts/build.sh)" >&2; exit 1; }
done
pin=(taskset -c 0)
command -v taskset > /dev/null || pin=()
printf 'odometry:\n  features:\n    type: sift\n' > "$out/sift.yaml"
printf 'odometry:\n  features:\n    type: orb\n' > "$out/orb.yaml"

metric() {  # metric METRICS_CSV SCOPE ID NAME
  awk -F, -v a="$2" -v b="$3" -v m="$4" '$1 == a && $2 == b && $4 == m {print $5; exit}' "$1"
}
declare -A sum
echo "| mission (preset, seed) | features | global pairs found | local pairs found | precision | maps (sessions) | map 0 ATE mm |"
echo "|---|---|---|---|---|---|---|"
for preset in demo textured hazy; do
  for seed in $seeds; do
    m="$out/${preset}_$seed"
    [ -d "$m" ] || "$bin/make_survey" --preset "$preset" --seed "$seed" --out "$m" --no-bag --quiet > /dev/null
    sessions=()  # in the spec's order (session ids by position)
    for name in $(awk '/^  - name: / {print $3}' "$m/survey.yaml"); do sessions+=(--session "$m/$name"); done
    for kind in sift orb; do
      run="$m/run_$kind"
      "${pin[@]}" "$bin/offline_slam" "${sessions[@]}" --out "$run" --config "$out/$kind.yaml" --quiet > "$run.log" 2>&1 ||
        { cat "$run.log" >&2; exit 1; }
      /usr/bin/python3 "$UWMS_REPO/src/tools/evaluate.py" --run "$run" --mission "$m" --report "$run/report" --no-plots \
        > /dev/null
      r="$run/report/metrics.csv"
      gf=$(metric "$r" loops inter found) gp=$(metric "$r" loops inter gt_pairs_keyframes)
      lf=$(metric "$r" loops intra found) lp=$(metric "$r" loops intra gt_pairs_keyframes)
      maps=$(awk -F, '$1 == "map" && $4 == "ate_rmse_m"' "$r" | wc -l)
      ate=$(awk -F, '$1 == "map" && $2 == "0" && $4 == "ate_rmse_m" {printf "%.1f", 1000 * $5}' "$r")
      echo "| $preset, $seed | $kind | $gf of $gp | $lf of $lp | $(metric "$r" loops all precision) | $maps ($(( ${#sessions[@]} / 2 ))) | $ate |"
      k="$preset $kind"
      sum[$k.gf]=$(( ${sum[$k.gf]:-0} + gf )) sum[$k.gp]=$(( ${sum[$k.gp]:-0} + gp ))
      sum[$k.lf]=$(( ${sum[$k.lf]:-0} + lf )) sum[$k.lp]=$(( ${sum[$k.lp]:-0} + lp ))
      sum[$k.maps]=$(( ${sum[$k.maps]:-0} + maps )) sum[$k.sessions]=$(( ${sum[$k.sessions]:-0} + ${#sessions[@]} / 2 ))
      sum[$k.ate]=$(echo "${sum[$k.ate]:-0} + $ate" | bc -l) sum[$k.n]=$(( ${sum[$k.n]:-0} + 1 ))
    done
  done
done
echo
echo "| preset | features | global pairs found | local pairs found | maps (sessions) | mean map 0 ATE mm |"
echo "|---|---|---|---|---|---|"
for preset in demo textured hazy; do
  for kind in sift orb; do
    k="$preset $kind"
    echo "| $preset | $kind | ${sum[$k.gf]} of ${sum[$k.gp]} | ${sum[$k.lf]} of ${sum[$k.lp]} | ${sum[$k.maps]} (${sum[$k.sessions]}) | $(printf "%.1f" "$(echo "${sum[$k.ate]} / ${sum[$k.n]}" | bc -l)") |"
  done
done
echo
echo "Seeds $seeds; offline_slam on one core, evaluate.py against each mission's ground truth. Raw outputs in $out."
