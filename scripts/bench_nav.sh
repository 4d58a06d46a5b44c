#!/usr/bin/env bash
# Nav benchmark: a nav prior must never make a map worse than no nav. Renders each flight of
# test/nav_bench.yaml with make_survey (black-outs of 5, 20 and 50 frames, turns at and beyond the
# vehicle's yaw rate, nav drift of 0.5 to 3 %, nav in ENU and NED, two sessions with and without
# visual overlap), runs offline_slam with --nav on and --nav off, scores both with evaluate.py
# and prints one markdown table with the rule "with nav <= without nav + 5 mm" per row
# (scripts/bench_nav.py --help says what each column is). Results: doc/benchmarks/nav.md.
# usage: scripts/bench_nav.sh [--rows NAME,...] [--config FILE] [OUT_DIR]   (needs a build: scripts/build.sh)
# Exit status 0 when every row passes, 1 when one fails, 2 when a tool fails.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
extra=()
while [ $# -gt 0 ]; do
  case "$1" in
    --rows|--config) extra+=("$1" "$2"); shift 2 ;;
    -h|--help) sed -n '2,9p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; exit 0 ;;
    -*) echo "bench_nav: unknown option $1" >&2; exit 2 ;;
    *) break ;;
  esac
done
out=${1:-$(mktemp -d /tmp/uwms_bench_nav.XXXXXX)}
mkdir -p "$out"
bin="$UWMS_WS/devel/lib/uw_multislam"
[ -x "$bin/offline_slam" ] && [ -x "$bin/make_survey" ] || { echo "bench_nav: build first (scripts/build.sh)" >&2; exit 2; }
exec /usr/bin/python3 "$UWMS_REPO/scripts/bench_nav.py" --bin "$bin" --out "$out" "${extra[@]}"
