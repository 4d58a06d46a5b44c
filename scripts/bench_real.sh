#!/usr/bin/env bash
# The real-data benchmark: offline_slam on the real survey ../shared/data/skerki_survey/s0 (148 ROV
# frames, pseudo ground truth and loops_gt.csv) and on the real AUV sequences ../shared/data/acfr/test1-6
# (each alone, as scripts/bench_odometry.sh runs them), each scored by src/tools/evaluate.py. Prints one
# markdown table (the accuracy table on real data) and, for skerki s0, the targets with PASS/FAIL:
#   - loop recall at precision 1 over keyframe pairs (recall) and over all ground-truth pairs
#     (recall_all: a pair is found when an accepted loop joins keyframes within one frame of each
#     of its frames), >= 0.95 both;
#   - the largest step between consecutive keyframes within 0.2 m of the ground truth's (kinks);
#   - e_k (mean relative error at the ground-truth loop pairs) <= 2 cm;
#   - no wrong loop (precision 1) on every sequence.
# With --audit, loop_audit's table follows: where the ground-truth pairs of s0 are lost, by stage.
# usage: scripts/bench_real.sh [--config FILE] [--audit] [OUT_DIR]   (needs a build: scripts/build.sh)
# One core (offline_slam --threads 1); about 1 minute without --audit on an idle core.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
config_args=()
audit=0
while [ $# -gt 0 ]; do
  case "$1" in
    --config) config_args=(--config "$2"); shift 2 ;;
    --audit) audit=1; shift ;;
    -h|--help) sed -n '2,15p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) break ;;
  esac
done
out=${1:-$(mktemp -d /tmp/uwms_bench_real.XXXXXX)}
mkdir -p "$out"
data="$UWMS_REPO/../shared/data"
bin="$UWMS_WS/devel/lib/uw_multislam"
[ -d "$data/skerki_survey/s0" ] && [ -d "$data/acfr" ] ||
  { echo "bench_real: $data/skerki_survey/s0 or $data/acfr not found (the shared data sits beside the repository)" >&2; exit 1; }
[ -x "$bin/offline_slam" ] || { echo "bench_real: build first (scripts/build.sh)" >&2; exit 1; }
evaluate="$UWMS_REPO/src/tools/evaluate.py"

# value REPORT SCOPE ID ESTIMATE METRIC -> the number (n/a when missing)
value() {
  awk -F, -v s="$2" -v i="$3" -v e="$4" -v m="$5" '$1==s && $2==i && $3==e && $4==m {v=$5} END {print (v=="" ? "n/a" : v)}' \
    "$1/metrics.csv"
}
fmt() {  # fmt PRINTF_FORMAT VALUE [SCALE]: n/a stays n/a
  if [ "$2" = "n/a" ]; then echo "n/a"; else printf "$1" "$(echo "$2 * ${3:-1}" | bc -l)"; fi
}

# run NAME DIR [evaluate options...]: offline_slam on one folder, then evaluate.py; prints one row.
run() {
  local name=$1 dir=$2; shift 2
  local t0 t1
  t0=$(date +%s.%N)
  "$bin/offline_slam" --session "$dir" --out "$out/$name" --threads 1 "${config_args[@]}" > "$out/$name.log" 2>&1 ||
    { echo "bench_real: offline_slam failed on $dir (see $out/$name.log)" >&2; exit 1; }
  t1=$(date +%s.%N)
  /usr/bin/python3 "$evaluate" --run "$out/$name" --session "$dir" --report "$out/$name/report" --no-plots "$@" \
    > "$out/$name.eval" 2>&1 || { echo "bench_real: evaluate.py failed on $name (see $out/$name.eval)" >&2; exit 1; }
  local r="$out/$name/report"
  local frames keyframes maps fallbacks
  frames=$(($(wc -l < "$dir/frames.csv") - 1))
  keyframes=$(value "$r" session 0 slam n_keyframes)
  maps=$(awk -F, 'NR > 1 {m[$3] = 1} END {print length(m)}' "$out/$name/trajectory.csv")
  fallbacks=$(sed -n 's/.* \([0-9]*\) fallbacks.*/\1/p' "$out/$name.log" | awk '{s += $1} END {print s + 0}')
  local acc cor prec rec rec_all
  acc=$(value "$r" loops all loops accepted); cor=$(value "$r" loops all loops correct)
  prec=$(value "$r" loops all loops precision); rec=$(value "$r" loops all loops recall)
  rec_all=$(value "$r" loops all loops recall_all)
  local wrong="n/a"
  [ "$acc" != "n/a" ] && [ "$cor" != "n/a" ] && wrong=$((acc - cor))
  echo "| $name | $frames | $keyframes | $maps | $fallbacks | $acc | $wrong | $(fmt %.3f "$prec") | $(fmt %.3f "$rec") |" \
    "$(fmt %.3f "$rec_all") | $(fmt %.2f "$(value "$r" session 0 slam ek_intra_m)" 100) |" \
    "$(fmt %.3f "$(value "$r" map 0 slam ate_rmse_m)") | $(fmt %.2f "$(value "$r" session 0 odometry end_drift_pct)") |" \
    "$(fmt %.2f "$(value "$r" session 0 slam end_drift_pct)") |" \
    "$(fmt %.2f "$(value "$r" session 0 slam max_step_m)") / $(fmt %.2f "$(value "$r" session 0 slam max_step_gt_m)") |" \
    "$(fmt %.2f "$(value "$r" session 0 slam max_step_err_m)") |" \
    "$(fmt %.1f "$(value "$r" session 0 slam max_turn_deg)") / $(fmt %.1f "$(value "$r" session 0 slam max_turn_gt_deg)") |" \
    "$(printf %.1f "$(echo "$t1 - $t0" | bc -l)") |"
}

skerki="$data/skerki_survey"
echo "### Real data: $(date -u '+%F %H:%M UTC'), $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), one core"
echo
echo "| sequence | frames | keyframes | maps | fallbacks | loops accepted | wrong | precision | recall (keyframe pairs) |" \
  "recall (all pairs) | e_k (cm) | map ATE (m) | odometry end drift % | slam end drift % |" \
  "largest step / gt's (m) | worst step error (m) | largest turn / gt's (deg) | seconds |"
echo "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
run skerki_s0 "$skerki/s0" --world-gt "$skerki/world_gt.csv" --loops-gt "$skerki/loops_gt.csv"
for seq in "$data"/acfr/test*; do run "acfr_$(basename "$seq")" "$seq"; done
echo
mean_drift=$(for f in "$out"/acfr_*/report; do value "$f" session 0 odometry end_drift_pct; done |
  awk '$1 != "n/a" {s += $1; n++} END {if (n) printf "%.2f", s / n; else print "n/a"}')
echo "acfr mean odometry end drift: $mean_drift % (main at f02f752: 8.66 %)"
echo
r="$out/skerki_s0/report"
check() {  # check LABEL VALUE CONDITION(awk, on v)
  local verdict="FAIL"
  [ "$2" != "n/a" ] && awk -v v="$2" "BEGIN {exit !($3)}" && verdict="PASS"
  echo "- $verdict: $1 ($2)"
}
echo "Targets on skerki_survey/s0:"
check "recall over keyframe pairs >= 0.95" "$(value "$r" loops all loops recall)" "v >= 0.95"
check "recall over all ground-truth pairs >= 0.95" "$(value "$r" loops all loops recall_all)" "v >= 0.95"
check "precision 1" "$(value "$r" loops all loops precision)" "v == 1"
check "largest keyframe step within 0.2 m of the ground truth's (excess, m)" \
  "$(value "$r" session 0 slam max_step_excess_m)" "v <= 0.2 && v >= -0.2"
check "e_k <= 2 cm (m)" "$(value "$r" session 0 slam ek_intra_m)" "v <= 0.02"
wrong_any=0
for f in "$out"/*/report/metrics.csv; do
  p=$(value "$(dirname "$f")" loops all loops precision)
  if [ "$p" != "n/a" ] && awk -v v="$p" 'BEGIN {exit !(v < 1)}'; then wrong_any=1; fi
done
[ "$wrong_any" = 0 ] && echo "- PASS: no wrong loop on any sequence" || echo "- FAIL: a wrong loop (see the table)"
if [ "$audit" = 1 ]; then
  [ -x "$bin/loop_audit" ] || { echo "bench_real: $bin/loop_audit missing: build first" >&2; exit 1; }
  echo
  echo "Where the ground-truth pairs of skerki_survey/s0 are lost (loop_audit; per pair: $out/skerki_s0_audit.csv):"
  echo
  "$bin/loop_audit" --session "$skerki/s0" --run "$out/skerki_s0" --loops-gt "$skerki/loops_gt.csv" \
    --config "$out/skerki_s0/config.yaml" --csv "$out/skerki_s0_audit.csv" --enhancement none --min-inliers 15
fi
echo
echo "runs in $out"
