#!/usr/bin/env bash
# OpenCV's SIFT against VLFeat's (odometry.features.sift_backend), measured as bench_frontend.sh
# measures the front-end options: one core (taskset -c 0, offline_slam --threads 1), both backends in
# the same run. Prints two markdown tables for doc/benchmarks/platforms.md:
#   1. per backend: ms per frame of the extractor (stage `features`) and of the whole pipeline on the
#      real 680x512 frames of ../shared/data/acfr/test1..6 and on the generated 320x240 demo mission;
#      the mean odometry end drift on acfr (evaluate.py, as bench_frontend.sh); the demo's loop
#      precision and recall;
#   2. stores mixing them: demo session s0 with one backend into a store (--db), s1 with the other,
#      and the global loops accepted and the join, against each backend alone.
# usage: scripts/bench_sift_backends.sh [OUT_DIR]   (needs a build with VLFeat; about 10 min)
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
out=${1:-$(mktemp -d /tmp/uwms_bench_sift_backends.XXXXXX)}
mkdir -p "$out"
data="$UWMS_REPO/../shared/data/acfr"
bin="$UWMS_WS/devel/lib/uw_multislam"
for t in offline_slam make_survey; do
  [ -x "$bin/$t" ] || { echo "bench_sift_backends: $bin/$t missing: build first (scripts/build.sh)" >&2; exit 1; }
done
[ -d "$data" ] || { echo "bench_sift_backends: $data not found (the shared data sits beside the repository)" >&2; exit 1; }
log() { echo "[bench_sift_backends] $*" >&2; }
one_core=(taskset -c 0)
command -v taskset > /dev/null || { log "taskset missing: runs are not pinned"; one_core=(); }

acfr=()
for seq in "$data"/test*; do acfr+=(--session "$seq"); done
[ -d "$out/demo" ] || { log "make_survey (demo)"; "$bin/make_survey" --out "$out/demo" --no-bag --quiet > /dev/null; }
demo=(--session "$out/demo/s0" --session "$out/demo/s1")
backends=(opencv vlfeat)
for b in "${backends[@]}"; do
  printf 'odometry:\n  features:\n    sift_backend: %s\n' "$b" > "$out/$b.yaml"
  "$bin/offline_slam" --config "$out/$b.yaml" --dump-config > /dev/null \
    || { echo "bench_sift_backends: this build cannot run sift_backend $b" >&2; exit 1; }
done

stage() {  # stage TIMING STAGE FIELD(2 calls, 3 total_ms)
  awk -F, -v s="$2" -v f="$3" '$1 == s {print $f}' "$1"
}
pipeline_stages="odometry_total hash hash_query local_candidates local_verify global_verify backend"
per_frame() {  # per_frame RUN_DIR -> pipeline ms per frame (image loading left out)
  local t="$1/timing.csv" sum=0 s v
  for s in $pipeline_stages; do v=$(stage "$t" "$s" 3); sum=$(echo "$sum + ${v:-0}" | bc -l); done
  printf "%.1f" "$(echo "$sum / $(stage "$t" odometry_total 2)" | bc -l)"
}
features_ms() { printf "%.1f" "$(echo "$(stage "$1/timing.csv" features 3) / $(stage "$1/timing.csv" features 2)" | bc -l)"; }
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
global_loops() { awk -F, 'NR > 1 && $5 == "global"' "$1/loops.csv" | wc -l; }
joined() { [ "$(awk 'NR > 1' "$1/links.csv" | wc -l)" -ge 1 ] && echo yes || echo no; }

declare -A row
for b in "${backends[@]}"; do
  log "offline_slam sift_backend $b (acfr 680x512, demo 320x240)"
  "${one_core[@]}" "$bin/offline_slam" "${acfr[@]}" --out "$out/${b}_680" --threads 1 --config "$out/$b.yaml" \
    > "$out/${b}_680.log" 2>&1 || { cat "$out/${b}_680.log" >&2; exit 1; }
  "${one_core[@]}" "$bin/offline_slam" "${demo[@]}" --out "$out/${b}_320" --threads 1 --config "$out/$b.yaml" \
    > "$out/${b}_320.log" 2>&1 || { cat "$out/${b}_320.log" >&2; exit 1; }
  evaluate "$out/${b}_680" "${acfr[@]}"
  evaluate "$out/${b}_320" --mission "$out/demo"
  m="$out/${b}_320/report/metrics.csv"
  row[$b]="| $b | $(features_ms "$out/${b}_680") | $(per_frame "$out/${b}_680") | $(features_ms "$out/${b}_320") \
| $(per_frame "$out/${b}_320") | $(mean_drift "$out/${b}_680/report") | $(metric "$m" loops all loops precision) \
| $(metric "$m" loops all loops recall) |"
done

declare -A mix
for first in "${backends[@]}"; do
  for second in "${backends[@]}"; do
    n="mix_${first}_${second}"
    rm -rf "$out/$n.db" "$out/${n}_a" "$out/${n}_b"
    log "store: demo s0 with $first, then s1 with $second"
    "${one_core[@]}" "$bin/offline_slam" --session "$out/demo/s0" --db "$out/$n.db" --out "$out/${n}_a" --threads 1 \
      --config "$out/$first.yaml" > "$out/${n}_a.log" 2>&1 || { cat "$out/${n}_a.log" >&2; exit 1; }
    "${one_core[@]}" "$bin/offline_slam" --session "$out/demo/s1" --db "$out/$n.db" --out "$out/${n}_b" --threads 1 \
      --config "$out/$second.yaml" > "$out/${n}_b.log" 2>&1 || { cat "$out/${n}_b.log" >&2; exit 1; }
    mix[$n]="| $first | $second | $(global_loops "$out/${n}_b") | $(joined "$out/${n}_b") |"
  done
done

cpu=$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)
echo "### SIFT backends: $(date -u '+%F %H:%M UTC'), $cpu, one core (taskset -c 0), load average $(cut -d' ' -f1 /proc/loadavg) at the end"
echo
echo "| sift_backend | 680×512 features ms/frame | 680×512 pipeline ms/frame | 320×240 features ms/frame | 320×240 pipeline ms/frame | acfr mean drift % | demo loop precision | demo loop recall |"
echo "|---|---|---|---|---|---|---|---|"
for b in "${backends[@]}"; do echo "${row[$b]}"; done
echo
echo "### One store, two backends: demo s0 into a store with the first, s1 with the second (--db)"
echo
echo "| s0 tracked with | s1 tracked with | global loops of s1 accepted | s1 joined to s0 |"
echo "|---|---|---|---|"
for first in "${backends[@]}"; do for second in "${backends[@]}"; do echo "${mix[mix_${first}_${second}]}"; done; done
echo
echo "Raw outputs in $out."
