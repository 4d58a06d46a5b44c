#!/usr/bin/env bash
# Scale benchmark (stores of many keyframes): bench_scale for stores of 1 k and 10 k synthetic keyframes (and
# 100 k with --100k: about 7 GB of store written to the temporary directory, checked first),
# one markdown table row each: RSS per stored keyframe after a restart on the store, the
# restart's load time, the median hash query and the median verification of one candidate
# (including its read from disk when paged). Not a test: numbers for this machine.
# usage: scripts/bench_scale.sh [--100k] [--dir DIR] [--config FILE]
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
sizes="1000 10000"
dir=${TMPDIR:-/tmp}
extra=()
while [ $# -gt 0 ]; do
  case "$1" in
    --100k) sizes="$sizes 100000"; shift ;;
    --dir) dir=$2; shift 2 ;;
    --config) extra+=(--config "$2"); shift 2 ;;
    *) echo "usage: scripts/bench_scale.sh [--100k] [--dir DIR] [--config FILE]" >&2; exit 2 ;;
  esac
done
bin="$UWMS_WS/devel/lib/uw_multislam/bench_scale"
[ -x "$bin" ] || { echo "bench_scale.sh: build first (scripts/build.sh)" >&2; exit 1; }
echo "| keyframes | RAM per stored keyframe kB | reload s | hash query ms (median) | verify one candidate ms (median) |"
echo "|---|---|---|---|---|"
for n in $sizes; do
  need_kb=$((n * 80))  # 74 kB per keyframe on disk, with margin
  free_kb=$(df -Pk "$dir" | awk 'NR == 2 { print $4 }')
  if [ "$free_kb" -lt "$need_kb" ]; then
    echo "bench_scale.sh: $n keyframes need about $((need_kb / 1024)) MB in $dir, $((free_kb / 1024)) MB free: skipped" >&2
    continue
  fi
  line=$("$bin" --keyframes "$n" --dir "$dir" "${extra[@]}")
  echo "$line" >&2
  # bench_scale keyframes=N ram_per_stored_keyframe_kB=X reload_s=Y hash_query_ms=Z verify_ms=W
  echo "$line" | awk '{ for (i = 2; i <= NF; ++i) { split($i, kv, "="); v[kv[1]] = kv[2] }
    printf "| %s | %s | %s | %s | %s |\n", v["keyframes"], v["ram_per_stored_keyframe_kB"], v["reload_s"],
           v["hash_query_ms"], v["verify_ms"] }'
done
