#!/usr/bin/env bash
# Bounded latency: a camera faster than the odometry. A generated 10 Hz mission is published live
# (each frame stamped when sent, scripts/bench_load_drive.py) through slam.launch (one nodelet
# manager, no store, its own master), a fresh pipeline per run:
#   1. every frame (~drop_policy oldest, a queue of 10000) at the mission's 10 Hz, which the
#      odometry keeps up with: the reference sessions and keyframes, and the mean ms per frame,
#      whose inverse is the sustainable rate;
#   2. at each multiple of the sustainable rate (default 2 and 4), today's drop-oldest queue
#      (~drop_policy oldest, ~queue_size 5) and the bounded-latency policy (newest, the default).
# Each row: the latency from image stamp to odometry/pose (median, p99, in ms and input periods),
# frames skipped and dropped, sessions and tracking losses (against the reference: no extra
# split), keyframes. The bar: newest at 2x, p99 <= 3 input periods and no extra session.
# Not a test: numbers for this machine (doc/benchmarks/load.md).
# usage: scripts/bench_load.sh [--multiples "2 4"] [--size WxH] [--length M] [OUT_DIR]
#   --size: the camera (default 320x240; 680x512 is the acfr camera's); --length: the lawnmower's legs, m (default 8).
# The earlier rate sweep (rates, drops, RSS, pose gap) is scripts/bench_load_sweep.sh.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
multiples="2 4"
size=320x240
length=8
while [ $# -gt 0 ]; do
  case "$1" in
    --multiples) multiples=$2; shift 2 ;;
    --size) size=$2; shift 2 ;;
    --length) length=$2; shift 2 ;;
    *) break ;;
  esac
done
out=${1:-$(mktemp -d /tmp/uwms_bench_load.XXXXXX)}
mkdir -p "$out"
bin="$UWMS_WS/devel/lib/uw_multislam"
[ -x "$bin/make_survey" ] || { echo "bench_load: build first (scripts/build.sh)" >&2; exit 1; }
set +u; source "$UWMS_WS/devel/setup.bash"; set -u
export ROS_MASTER_URI=${BENCH_MASTER_URI:-http://localhost:11392}  # a master of its own
log() { echo "[bench_load] $*" >&2; }

width=${size%x*}; height=${size#*x}
focal=$(awk -v w="$width" 'BEGIN { printf "%.1f", w * 300 / 320 }')  # the demo camera's field of view
if [ ! -f "$out/mission/s0.bag" ]; then
  cat > "$out/survey.yaml" << EOF
seed: 3
world: {width_m: 16, height_m: 12, featureless_fraction: 0.0}
sessions:
  - name: s0
    camera: {image_width: $width, image_height: $height, fx: $focal, fy: $focal, cx: $(( width / 2 )).5, cy: $(( height / 2 )).5}
    mission: {pattern: lawnmower, start_m: [3, 3], length_m: $length, width_m: 4.2, leg_spacing_m: 1.4, laps: 1.0,
              speed_m_s: 0.5, frame_period_s: 0.1, altitude_m: 2.5, start_time_s: 0}
EOF
  log "make_survey --config $out/survey.yaml"
  "$bin/make_survey" --config "$out/survey.yaml" --out "$out/mission" --quiet > /dev/null
fi
bag="$out/mission/s0.bag"

# The ROS-side parameters per policy (slam.launch config:=).
config() {  # policy queue_size -> file
  local f="$out/default_$1_$2.yaml"
  sed -e "s/^  drop_policy: newest$/  drop_policy: $1/" -e "s/^  queue_size: 5$/  queue_size: $2/" \
    "$UWMS_REPO/config/default.yaml" > "$f"
  grep -q "^  drop_policy: $1$" "$f" && grep -q "^  queue_size: $2$" "$f" \
    || { echo "bench_load: drop_policy / queue_size not found in config/default.yaml" >&2; exit 1; }
  echo "$f"
}

port=${ROS_MASTER_URI##*:}
roscore -p "$port" > "$out/roscore.log" 2>&1 &
core_pid=$!
launch_pid=""
cleanup() {
  [ -n "$launch_pid" ] && kill -INT "$launch_pid" 2> /dev/null && wait "$launch_pid" 2> /dev/null || true
  kill -INT "$core_pid" 2> /dev/null && wait "$core_pid" 2> /dev/null || true
}
trap cleanup EXIT
for _ in $(seq 50); do rostopic list > /dev/null 2>&1 && break; sleep 0.2; done

run() {  # name policy queue_size rate -> JSON line in $out/<name>.json
  local name=$1 policy=$2 queue=$3 rate=$4
  rosparam delete /uw_multislam > /dev/null 2>&1 || true
  roslaunch uw_multislam slam.launch store_path:=none camera_mount:="0 0 0 0" config:="$(config "$policy" "$queue")" \
    > "$out/launch_$name.log" 2>&1 &
  launch_pid=$!
  /usr/bin/python3 "$UWMS_REPO/scripts/bench_load_drive.py" "$bag" "$rate" > "$out/$name.json" 2> "$out/drive_$name.log" \
    || echo '{"error": "the driver failed"}' > "$out/$name.json"
  kill -INT "$launch_pid" 2> /dev/null || true
  wait "$launch_pid" 2> /dev/null || true
  launch_pid=""
  log "$name: $(cat "$out/$name.json")"
}

log "reference: every frame at 10 Hz"
run reference oldest 10000 10
sustainable=$(/usr/bin/python3 -c 'import json,sys; print("%.1f" % (1000.0 / json.load(open(sys.argv[1]))["ms_per_frame_mean"]))' \
  "$out/reference.json")
for m in $multiples; do
  rate=$(awk -v s="$sustainable" -v m="$m" 'BEGIN { printf "%.1f", s * m }')
  run "oldest_${m}x" oldest 5 "$rate"
  run "newest_${m}x" newest 5 "$rate"
done

/usr/bin/python3 - "$out" "$sustainable" "$size" $multiples << 'PY'
import json, os, sys
out, sustainable, size, multiples = sys.argv[1], float(sys.argv[2]), sys.argv[3], sys.argv[4:]
ref = json.load(open(os.path.join(out, "reference.json")))
print("### Bounded latency: %d frames of %s at 10 Hz (a generated lawnmower), slam.launch, %s" % (
    ref["frames"], size, os.popen("date -u +%F").read().strip()))
print()
print("Reference, every frame at 10 Hz (drop_policy oldest, queue 10000): %d processed, %d sessions, %d tracking "
      "losses, %d keyframes, %.1f ms per frame: sustainable rate %.1f frames/s." % (
          ref["frames_processed"], ref["sessions"], ref["tracking_losses"], ref["keyframes"], ref["ms_per_frame_mean"],
          sustainable))
print()
print("| policy | rate | frames/s | processed | skipped for newest | dropped (queue full) | sessions | tracking losses "
      "| keyframes | latency median ms (periods) | latency p99 ms (periods) |")
print("|---|---|---|---|---|---|---|---|---|---|---|")
verdict = []
for m in multiples:
    for policy in ("oldest", "newest"):
        r = json.load(open(os.path.join(out, "%s_%sx.json" % (policy, m))))
        if "error" in r:
            print("| %s | %sx | (%s) |" % (policy, m, r["error"]))
            continue
        print("| %s%s | %sx | %.1f | %d | %d | %d | %d | %d | %d | %.0f (%.1f) | %.0f (%.1f) |" % (
            policy, " (queue 5, today's)" if policy == "oldest" else "", m, r["rate_hz"], r["frames_processed"],
            r["skipped_for_newest"], r["dropped_queue_full"], r["sessions"], r["tracking_losses"], r["keyframes"],
            r["latency_median_ms"], r["latency_median_periods"], r["latency_p99_ms"], r["latency_p99_periods"]))
        if policy == "newest" and m == "2":
            ok = r["latency_p99_periods"] <= 3.0 and r["sessions"] <= ref["sessions"]
            verdict.append("newest at 2x: p99 %.1f input periods (bar: <= 3), %d sessions (every frame: %d): %s" % (
                r["latency_p99_periods"], r["sessions"], ref["sessions"], "meets the bar" if ok else "MISSES the bar"))
print()
for v in verdict:
    print(v)
PY
echo "(logs and JSON in $out)"
