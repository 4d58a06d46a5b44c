#!/usr/bin/env bash
# The benchmark report: ONE markdown table with the machine and the date.
#   - ms per keyframe of each stage (feature extraction, matching, RANSAC, hashing, hash query,
#     loop verification, optimisation) from offline_slam's timing.csv on the generated demo
#     mission (two sessions, one core), and the whole pipeline's time as a ratio to feature
#     extraction alone (target <= 1.3x);
#   - memory per keyframe (offline_slam's peak RSS, one session against two: the slope), and the
#     store's bytes per keyframe (bench_store);
#   - growth from 100 to 10k keyframes: hash query (bench_loops --sizes), sparse optimisation time
#     and peak RSS (bench_backend --cost, loops = 10 % of the keyframes);
#   - IEKF against sparse (bench_backend --cost 1000), HALOC against brute-force loop search on the
#     demo mission (bench_loops), our odometry against the naive OpenCV baseline on
#     ../shared/data/acfr (scripts/bench_odometry.sh; skipped when the data is not there);
#   - the front-end options table (scripts/bench_frontend.sh): ms/frame per odometry option
#     on one core at 680x512 (acfr) and 320x240 (demo) beside OpenCV SIFT alone and the naive
#     odometer in the same run, acfr drift and demo loop precision/recall; printed after the table.
# usage: scripts/bench.sh [--quick] [OUT_DIR]   (needs a build: scripts/build.sh)
#   --quick: no 10k-keyframe optimisation, no 10k-keyframe store, no odometry baseline, no front-end
#   options table (155 s on
#   2026-11-23 on this 2-core machine; without it several minutes more). The raw outputs stay in OUT_DIR.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
quick=0
if [ "${1:-}" = "--quick" ]; then quick=1; shift; fi
out=${1:-$(mktemp -d /tmp/uwms_bench.XXXXXX)}
mkdir -p "$out"
bin="$UWMS_WS/devel/lib/uw_multislam"
for t in offline_slam make_survey bench_loops bench_backend bench_store; do
  [ -x "$bin/$t" ] || { echo "bench: $bin/$t missing: build first (scripts/build.sh)" >&2; exit 1; }
done
log() { echo "[bench] $*" >&2; }
start_s=$(date +%s)

# --- the demo mission, one session and two, on one core -------------------------------------------
[ -d "$out/demo" ] || { log "make_survey (demo)"; "$bin/make_survey" --out "$out/demo" --no-bag --quiet > /dev/null; }
rss_kb() {  # rss_kb LOG: peak RSS written by /usr/bin/time -f
  sed -n 's/^peak_rss_kb \([0-9]*\)$/\1/p' "$1" | tail -n 1
}
run_slam() {  # run_slam NAME SESSION_DIRS...
  local name=$1; shift
  local args=() d
  for d in "$@"; do args+=(--session "$d"); done
  log "offline_slam $name"
  /usr/bin/time -f 'peak_rss_kb %M' "$bin/offline_slam" "${args[@]}" --out "$out/$name" --threads 1 \
    > "$out/$name.log" 2> "$out/$name.err" || { cat "$out/$name.err" >&2; exit 1; }
}
run_slam run1 "$out/demo/s0"
run_slam run2 "$out/demo/s0" "$out/demo/s1"
kf1=$(($(wc -l < "$out/run1/odometry.csv") - 1))
kf2=$(($(wc -l < "$out/run2/odometry.csv") - 1))
rss1=$(rss_kb "$out/run1.err"); rss2=$(rss_kb "$out/run2.err")
timing="$out/run2/timing.csv"
total() {  # total STAGE...: the sum of their total_ms in the two-session run
  local s sum=0 v
  for s in "$@"; do
    v=$(awk -F, -v s="$s" '$1==s {print $3}' "$timing"); sum=$(echo "$sum + ${v:-0}" | bc -l)
  done
  echo "$sum"
}
per_kf() { printf "%.3f" "$(echo "$(total "$@") / $kf2" | bc -l)"; }
frames2=$(awk -F, '$1=="odometry_total" {print $2}' "$timing")
features_ms=$(total features)
pipeline_ms=$(total odometry_total hash hash_query local_candidates local_verify global_verify backend)
ratio=$(printf "%.2f" "$(echo "$pipeline_ms / $features_ms" | bc -l)")
mem_per_kf=$(printf "%.0f" "$(echo "($rss2 - $rss1) / ($kf2 - $kf1)" | bc -l)")

# --- loop search: hash store growth, the default hash and HALOC against brute force ----------------
log "bench_loops"
"$bin/bench_loops" --session "$out/demo/s0" --session "$out/demo/s1" --sizes 100,1000,10000 > "$out/bench_loops.md" 2>&1
query_row() {  # query_row N -> "median ms|store MB"
  awk -F'|' -v n="$1" '{gsub(/ /, "", $2)} $2==n {gsub(/ /, "", $3); gsub(/ /, "", $9); print $3 "|" $9; exit}' \
    "$out/bench_loops.md"
}
method_row() {  # method_row NAME -> "accepted|correct|recall|ms/kf"
  awk -F'|' -v n="$1" '{m=$2; gsub(/^ +| +$/, "", m)} m==n {for (i=3;i<=15;i++) gsub(/^ +| +$/, "", $i); print $4 "|" $5 "|" $9 "|" $14; exit}' \
    "$out/bench_loops.md"
}

# --- optimisation: growth and IEKF against sparse --------------------------------------------------
cost() {  # cost OPT N -> "optimise ms|one more loop ms|peak MB"
  local loops=$(($2 / 10))
  "$bin/bench_backend" --cost "$2" --loops "$loops" --optimizer "$1" > "$out/cost_$1_$2.md" 2>&1
  awk -F'|' '$2 ~ /(sparse|iekf)/ {for (i=2;i<=9;i++) gsub(/ /, "", $i); print $6 "|" $7 "|" $8; exit}' "$out/cost_$1_$2.md"
}
sizes=(100 1000 10000)
[ "$quick" = 1 ] && sizes=(100 1000)
declare -A sparse
for n in "${sizes[@]}"; do log "bench_backend --cost $n sparse"; sparse[$n]=$(cost sparse "$n"); done
log "bench_backend --cost 1000 iekf"; iekf1k=$(cost iekf 1000)
[ -n "${sparse[1000]:-}" ] || sparse[1000]=$(cost sparse 1000)

# --- the store ---------------------------------------------------------------------------------------
store_n=1000; [ "$quick" = 1 ] || store_n="1000 10000"
log "bench_store"
# shellcheck disable=SC2086
"$bin/bench_store" $(for n in $store_n; do echo --keyframes "$n"; done) > "$out/bench_store.md" 2>&1 || true
store_row() {  # store_row N -> "kB per keyframe|write ms per keyframe"
  awk -F'|' -v n="$1" '{gsub(/ /, "", $2)} $2==n {gsub(/ /, "", $4); gsub(/ /, "", $5); printf "%.1f|%s", $4 / 1000, $5; exit}' \
    "$out/bench_store.md"
}

# --- odometry against the OpenCV baseline ------------------------------------------------------------
odo="skipped (--quick)"
if [ "$quick" = 0 ]; then
  if [ -d "$UWMS_REPO/../shared/data/acfr" ]; then
    log "bench_odometry.sh"
    bash "$UWMS_REPO/scripts/bench_odometry.sh" "$out/odometry" > "$out/bench_odometry.md" 2>&1 || true
    odo=$(awk -F'|' '$2 ~ /mean/ {gsub(/ /, "", $3); gsub(/ /, "", $4); print "mean end drift " $3 " % (ours) vs " $4 " % (baseline), ACFR test1-6"; exit}' \
      "$out/bench_odometry.md")
    [ -n "$odo" ] || odo="failed (see $out/bench_odometry.md)"
    log "bench_frontend.sh"
    bash "$UWMS_REPO/scripts/bench_frontend.sh" "$out/frontend" > "$out/bench_frontend.md" 2> "$out/bench_frontend.err" ||
      echo "bench_frontend.sh failed (see $out/bench_frontend.err)" > "$out/bench_frontend.md"
  else
    odo="skipped (../shared/data/acfr not found)"
  fi
fi

# --- the table ------------------------------------------------------------------------------------------
cpu=$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)
IFS='|' read -r q100 m100 <<< "$(query_row 100)"
IFS='|' read -r q1k m1k <<< "$(query_row 1000)"
IFS='|' read -r q10k m10k <<< "$(query_row 10000)"
IFS='|' read -r h5a h5c h5r h5ms <<< "$(method_row 'haloc (paper) k = 10')"
IFS='|' read -r sda sdc sdr sdms <<< "$(method_row 'sorted_dct (default) k = 10')"
IFS='|' read -r bfa bfc bfr bfms <<< "$(method_row 'brute force')"
growth_opt="" growth_rss=""
for n in "${sizes[@]}"; do
  IFS='|' read -r o l r <<< "${sparse[$n]}"
  growth_opt+="${growth_opt:+ / }$o"; growth_rss+="${growth_rss:+ / }$r"
done
IFS='|' read -r so sl sr <<< "${sparse[1000]}"
IFS='|' read -r io il ir <<< "$iekf1k"
label=$(IFS=/; echo "${sizes[*]}")
store_cells=""
for n in $store_n; do
  IFS='|' read -r skb sms <<< "$(store_row "$n")"
  store_cells+="${store_cells:+; }$n keyframes: $skb kB, $sms ms written"
done

echo "### uw_multislam benchmark: $(date -u '+%F %H:%M UTC'), $cpu, $(nproc) cores$([ "$quick" = 1 ] && echo ', --quick')"
echo
echo "| what | measure | value |"
echo "|---|---|---|"
echo "| machine | CPU, cores, date | $cpu, $(nproc) cores, $(date -u +%F) |"
echo "| stages (demo mission, 2 sessions, $frames2 frames, $kf2 keyframes, 1 core), ms per keyframe | feature extraction (SIFT, n = 500) | $(per_kf features) |"
echo "| | enhancement (CLAHE) | $(per_kf enhance) |"
echo "| | matching | $(per_kf match) |"
echo "| | RANSAC | $(per_kf ransac) |"
echo "| | hashing | $(per_kf hash) |"
echo "| | hash query | $(per_kf hash_query) |"
echo "| | loop verification (local candidates + local + global RANSAC) | $(per_kf local_candidates local_verify global_verify) |"
echo "| | optimisation (sparse back-end) | $(per_kf backend) |"
echo "| | whole pipeline (odometry of every frame + loops + back-end) | $(per_kf odometry_total hash hash_query local_candidates local_verify global_verify backend) |"
echo "| | whole pipeline / feature extraction (target ≤ 1.3×) | ${ratio}× |"
echo "| memory | per keyframe, pipeline (peak RSS, $kf1 → $kf2 keyframes: $((rss1 / 1024)) → $((rss2 / 1024)) MB) | $mem_per_kf kB |"
echo "| | per keyframe in the session store on disk (bench_store, fsync per keyframe) | ${store_cells:-n/a} |"
echo "| growth, 100 / 1000 / 10000 keyframes | hash query, median ms | $q100 / $q1k / $q10k |"
echo "| | hash store, MB | $m100 / $m1k / $m10k |"
echo "| growth, $label keyframes (bench_backend --cost) | sparse optimisation of all loops (10 % of keyframes), ms | $growth_opt |"
echo "| | sparse optimisation, peak RSS MB | $growth_rss |"
echo "| IEKF vs sparse (1000 keyframes, 100 loops) | optimise all loops ms; one more loop ms; peak RSS MB | IEKF $io; $il; $ir — sparse $so; $sl; $sr |"
echo "| the default hash (sorted_dct, k = 10), the paper's HALOC (k = 10) and brute force (bench_loops, demo s1 → s0) | accepted / correct / recall / ms per keyframe | sorted_dct $sda / $sdc / $sdr / $sdms — HALOC $h5a / $h5c / $h5r / $h5ms — brute force $bfa / $bfc / $bfr / $bfms |"
echo "| our odometry vs naive OpenCV baseline | end drift | $odo |"
if [ -f "$out/bench_frontend.md" ]; then echo; cat "$out/bench_frontend.md"; fi
echo
echo "Run time $(( $(date +%s) - start_s )) s; raw outputs in $out."
