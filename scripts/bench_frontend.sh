#!/usr/bin/env bash
# Front-end options, measured (feature options, threads, image size): two markdown tables. The first: every
# run pinned to one core (taskset -c 0, offline_slam --threads 1), the references in the same run
# so that the ratios hold on a noisy machine. The second: each option on two cores (taskset -c 0,1,
# offline_slam --threads 2) against the same one-core run, wall ms/frame from offline_slam's
# throughput line, and whether the outputs are byte-identical.
#   rows: each odometry option (SIFT as today, SIFT without the x2 upsampling, KLT tracking between
#   keyframes with either, ORB with and without KLT), then the references: OpenCV SIFT alone (default settings, as the naive
#   odometer runs it) and the naive odometer (baseline_odometry: SIFT + ratio test +
#   estimateAffinePartial2D between consecutive frames);
#   columns: whole-pipeline ms per frame (odometry of every frame + hashing + loop search and
#   verification + back-end; image loading left out, for the references too) on the real 680x512
#   frames of ../shared/data/acfr/test1..6 and on the generated 320x240 demo mission (2 sessions);
#   the ratio to the naive odometer at 680x512; the share of frames that ran the extractor; the mean odometry
#   end drift on acfr test1..6 (evaluate.py); loop precision and recall on the demo mission.
# usage: scripts/bench_frontend.sh [OUT_DIR]   (needs a build: scripts/build.sh; about 5 min)
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
out=${1:-$(mktemp -d /tmp/uwms_bench_frontend.XXXXXX)}
mkdir -p "$out"
data="$UWMS_REPO/../shared/data/acfr"
bin="$UWMS_WS/devel/lib/uw_multislam"
for t in offline_slam baseline_odometry make_survey; do
  [ -x "$bin/$t" ] || { echo "bench_frontend: $bin/$t missing: build first (scripts/build.sh)" >&2; exit 1; }
done
[ -d "$data" ] || { echo "bench_frontend: $data not found (the shared data sits beside the repository)" >&2; exit 1; }
log() { echo "[bench_frontend] $*" >&2; }
one_core=(taskset -c 0)
two_cores=(taskset -c 0,1)
command -v taskset > /dev/null || { log "taskset missing: runs are not pinned"; one_core=(); two_cores=(); }

acfr=()
for seq in "$data"/test*; do acfr+=(--session "$seq"); done
[ -d "$out/demo" ] || { log "make_survey (demo)"; "$bin/make_survey" --out "$out/demo" --no-bag --quiet > /dev/null; }
demo=(--session "$out/demo/s0" --session "$out/demo/s1")

# The options: name and the slam.yaml overlay (missing keys keep the defaults).
names=(sift sift_no_upsampling klt_sift klt_sift_no_upsampling orb klt_orb)
declare -A yaml
yaml[sift]=$'odometry:\n  klt:\n    enabled: false\n'
yaml[sift_no_upsampling]=$'odometry:\n  features:\n    first_octave: 0\n  klt:\n    enabled: false\n'
yaml[klt_sift]=$'odometry:\n  klt:\n    enabled: true\n'
yaml[klt_sift_no_upsampling]=$'odometry:\n  features:\n    first_octave: 0\n  klt:\n    enabled: true\n'
yaml[orb]=$'odometry:\n  features:\n    type: orb\n  klt:\n    enabled: false\n'
yaml[klt_orb]=$'odometry:\n  features:\n    type: orb\n  klt:\n    enabled: true\n'
declare -A label
label[sift]="SIFT (x2 upsampling, as before)"
label[sift_no_upsampling]="SIFT without upsampling (first_octave 0)"
label[klt_sift]="KLT between keyframes + SIFT"
label[klt_sift_no_upsampling]="KLT between keyframes + SIFT without upsampling"
label[orb]="ORB (binary, Hamming matching)"
label[klt_orb]="KLT between keyframes + ORB"

stage_total() {  # stage_total TIMING STAGE... -> sum of total_ms
  awk -F, -v list="${*:2}" 'BEGIN {n = split(list, s, " "); for (i = 1; i <= n; ++i) want[s[i]] = 1}
    ($1 in want) {t += $3} END {printf "%.3f", t}' "$1"
}
stage_calls() { awk -F, -v s="$2" '$1 == s {print $2}' "$1"; }
pipeline_stages="odometry_total hash hash_query local_candidates local_verify global_verify backend"
per_frame() {  # per_frame RUN_DIR -> pipeline ms per frame
  local t="$1/timing.csv"
  printf "%.1f" "$(echo "$(stage_total "$t" $pipeline_stages) / $(stage_calls "$t" odometry_total)" | bc -l)"
}
sift_share() {  # share of frames that ran the extractor (SIFT or ORB: stage features), %
  local t="$1/timing.csv"
  printf "%.0f" "$(echo "100 * $(stage_calls "$t" features) / $(stage_calls "$t" odometry_total)" | bc -l)"
}
metric() {  # metric METRICS_CSV SCOPE ID ESTIMATE NAME
  awk -F, -v a="$2" -v b="$3" -v c="$4" -v m="$5" '$1 == a && $2 == b && $3 == c && $4 == m {print $5; exit}' "$1"
}
mean_drift() {  # mean_drift REPORT_DIR -> mean odometry end drift of sessions 0..5, %
  local sum=0 s v
  for s in 0 1 2 3 4 5; do
    v=$(metric "$1/metrics.csv" session "$s" odometry end_drift_pct)
    [ -n "$v" ] && [ "$v" != "n/a" ] || { echo "n/a"; return; }
    sum=$(echo "$sum + $v" | bc -l)
  done
  printf "%.2f" "$(echo "$sum / 6" | bc -l)"
}
evaluate() {  # evaluate RUN_DIR SESSION_ARGS... (report into RUN_DIR/report)
  local run=$1; shift
  /usr/bin/python3 "$UWMS_REPO/src/tools/evaluate.py" --run "$run" "$@" --report "$run/report" --no-plots > /dev/null
}

# References first: the naive odometer (its timing.csv has OpenCV SIFT alone as a stage).
log "baseline_odometry (acfr, demo)"
"${one_core[@]}" "$bin/baseline_odometry" "${acfr[@]}" --out "$out/naive_680" > "$out/naive_680.log" 2>&1
"${one_core[@]}" "$bin/baseline_odometry" "${demo[@]}" --out "$out/naive_320" > "$out/naive_320.log" 2>&1
evaluate "$out/naive_680" "${acfr[@]}"
naive_ms() {  # whole step without the image loading, ms per frame
  local t="$1/timing.csv"
  printf "%.1f" "$(echo "($(stage_total "$t" baseline_total) - $(stage_total "$t" load_image)) / $(stage_calls "$t" baseline_total)" | bc -l)"
}
sift_ms() { awk -F, '$1 == "sift" {printf "%.1f", $4}' "$1/timing.csv"; }
naive680=$(naive_ms "$out/naive_680")

declare -A row two_row
wall_ms() { sed -n 's/^throughput: .*, \([0-9.]*\) ms\/frame .*/\1/p' "$1"; }  # offline_slam's wall ms/frame
same_outputs() {  # same_outputs RUN_A RUN_B -> "same" when every output but timing.csv is byte-identical
  local f
  for f in "$1"/*.csv; do
    [ "$(basename "$f")" = timing.csv ] && continue
    cmp -s "$f" "$2/$(basename "$f")" || { echo "DIFFERENT ($(basename "$f"))"; return; }
  done
  echo "same"
}
for n in "${names[@]}"; do
  cfg="$out/$n.yaml"
  printf "%s" "${yaml[$n]}" > "$cfg"
  log "offline_slam $n (acfr 680x512, demo 320x240)"
  "${one_core[@]}" "$bin/offline_slam" "${acfr[@]}" --out "$out/${n}_680" --threads 1 --config "$cfg" \
    > "$out/${n}_680.log" 2>&1 || { cat "$out/${n}_680.log" >&2; exit 1; }
  "${one_core[@]}" "$bin/offline_slam" "${demo[@]}" --out "$out/${n}_320" --threads 1 --config "$cfg" \
    > "$out/${n}_320.log" 2>&1 || { cat "$out/${n}_320.log" >&2; exit 1; }
  # Two cores (a second core preparing frames): --threads 2 on cores 0 and 1, the same outputs expected.
  for size in 680 320; do
    if [ "$size" = 680 ]; then set -- "${acfr[@]}"; else set -- "${demo[@]}"; fi
    "${two_cores[@]}" "$bin/offline_slam" "$@" --out "$out/${n}_${size}_t2" --threads 2 --config "$cfg" \
      > "$out/${n}_${size}_t2.log" 2>&1 || { cat "$out/${n}_${size}_t2.log" >&2; exit 1; }
  done
  evaluate "$out/${n}_680" "${acfr[@]}"
  evaluate "$out/${n}_320" --mission "$out/demo"  # the mission's world_gt.csv judges the global loops
  ms680=$(per_frame "$out/${n}_680")
  m="$out/${n}_320/report/metrics.csv"
  two=""
  for size in 680 320; do
    w1=$(wall_ms "$out/${n}_${size}.log") w2=$(wall_ms "$out/${n}_${size}_t2.log")
    two="$two | $w1 | $w2 | $(printf "%.2f" "$(echo "$w1 / $w2" | bc -l)")×"
  done
  two_row[$n]="| ${label[$n]}$two | $(same_outputs "$out/${n}_680" "$out/${n}_680_t2") / $(same_outputs "$out/${n}_320" "$out/${n}_320_t2") |"
  row[$n]="| ${label[$n]} | $ms680 | $(printf "%.2f" "$(echo "$ms680 / $naive680" | bc -l)")× | $(per_frame "$out/${n}_320") \
| $(sift_share "$out/${n}_680") % / $(sift_share "$out/${n}_320") % | $(mean_drift "$out/${n}_680/report") \
| $(metric "$m" loops all loops precision) | $(metric "$m" loops all loops recall) |"
done

cpu=$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)
echo "### Front-end options: $(date -u '+%F %H:%M UTC'), $cpu, one core (taskset -c 0), load average $(cut -d' ' -f1 /proc/loadavg) at the end"
echo
echo "| option | 680×512 ms/frame (acfr, 48 frames) | / naive | 320×240 ms/frame (demo, $(stage_calls "$out/sift_320/timing.csv" odometry_total) frames) | frames extracted (680 / 320) | acfr mean drift % | demo loop precision | demo loop recall |"
echo "|---|---|---|---|---|---|---|---|"
for n in "${names[@]}"; do echo "${row[$n]}"; done
echo "| reference: OpenCV SIFT alone (default settings) | $(sift_ms "$out/naive_680") | $(printf "%.2f" "$(echo "$(sift_ms "$out/naive_680") / $naive680" | bc -l)")× | $(sift_ms "$out/naive_320") | 100 % / 100 % | | | |"
echo "| reference: naive odometer (baseline_odometry) | $naive680 | 1.00× | $(naive_ms "$out/naive_320") | 100 % / 100 % | $(mean_drift "$out/naive_680/report") | | |"
echo
echo "### Two cores: offline_slam --threads 2 on cores 0 and 1 (taskset -c 0,1) against --threads 1 on core 0, same run"
echo
echo "| option | 680×512 one core ms/frame | two cores | speed-up | 320×240 one core ms/frame | two cores | speed-up | outputs (680 / 320) |"
echo "|---|---|---|---|---|---|---|---|"
for n in "${names[@]}"; do echo "${two_row[$n]}"; done
echo
echo "Two cores: wall ms per frame from offline_slam's throughput line (image reading included, start-up and the end's output files not); outputs: every CSV file but timing.csv compared byte for byte."
echo
echo "Pipeline ms/frame: offline_slam's timing.csv, stages $pipeline_stages, per frame (image loading left out, for the naive odometer too). Raw outputs in $out."
