#!/usr/bin/env bash
# Load sweep (scripts/bench_load_sweep.sh): a generated mission bag replayed through slam.launch (nodelet manager,
# default queues) at increasing rates. For each rate a fresh pipeline; at the end the counters are
# read from /diagnostics (scripts/diagnostics_snapshot.py) and the nodelet manager's peak RSS
# (VmHWM) from /proc. Prints one markdown table and the highest rate held without a dropped or
# unpaired frame; then the longest gap in the back-end's current pose during an optimisation of
# a 5,000-keyframe map (scripts/bench_pose_gap.py). Not a test: numbers for this machine.
# usage: scripts/bench_load_sweep.sh [--rates "1 2 5 10 20 40 80 160"] [--preset NAME] [--prepare-threads N]
#                                    [--drop-policy newest|oldest] [OUT_DIR]
#   default mission: make_survey --preset demo, session s0 (its bag); rates 1 2 5 10 20 40 80 160.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/bench_load_common.sh"
rates="1 2 5 10 20 40 80 160"
preset=demo
prepare_threads=0  # the odometry nodelet's ~prepare_threads (a second core preparing frames)
policy=newest      # its ~drop_policy
while [ $# -gt 0 ]; do
  case "$1" in
    --rates) rates=$2; shift 2 ;;
    --preset) preset=$2; shift 2 ;;
    --prepare-threads) prepare_threads=$2; shift 2 ;;
    --drop-policy) policy=$2; shift 2 ;;
    *) break ;;
  esac
done
bench_init bench_load_sweep 11391 "${1:-}"
# The ROS-side parameters (slam.launch config:=).
bench_config "$out/default.yaml" prepare_threads="$prepare_threads" drop_policy="$policy"

[ -d "$out/mission" ] || { log "make_survey --preset $preset"; "$bin/make_survey" --preset "$preset" --out "$out/mission" --quiet > /dev/null; }
bag="$out/mission/s0.bag"
frames=$(/usr/bin/python3 -c 'import rosbag,sys; b=rosbag.Bag(sys.argv[1]); print(b.get_message_count("/camera/image_raw")); print(b.get_end_time()-b.get_start_time())' "$bag" | paste -sd' ')
read -r n_frames duration_s <<< "$frames"
log "bag: $n_frames frames over $duration_s s"

bench_roscore

echo "### Load: $(basename "$bag") ($n_frames frames, $(printf %.0f "$duration_s") s) through slam.launch (odometry prepare_threads $prepare_threads, drop_policy $policy), $(date -u +%F), $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), $(nproc) cores"
echo
echo "| rate | frames/s offered | images received | processed | dropped (odometry queue) | not paired | keyframes | keyframes/s | loop detector dropped | loops | odometry ms/frame mean / max | manager peak RSS MB |"
echo "|---|---|---|---|---|---|---|---|---|---|---|---|"
best=""
for rate in $rates; do
  bench_launch "$out/launch_$rate.log" "$out/default.yaml"  # a fresh pipeline per rate
  for _ in $(seq 100); do  # the odometry subscribes (through the nodelet manager)
    rostopic info /camera/image_raw 2> /dev/null | grep -q "/uw_multislam/manager" && break; sleep 0.2
  done
  sleep 2
  manager_pid=$(rosnode info /uw_multislam/manager 2> /dev/null | sed -n 's/^Pid: \([0-9]*\)/\1/p')
  rosbag play -q -r "$rate" "$bag" --topics /camera/image_raw /camera/camera_info /altitude > "$out/play_$rate.log" 2>&1
  sleep 3  # the queues drain
  /usr/bin/python3 "$UWMS_REPO/scripts/diagnostics_snapshot.py" --wait 2.5 > "$out/diag_$rate.json" || true
  rss_kb=$(awk '/VmHWM/ {print $2}' "/proc/$manager_pid/status" 2> /dev/null || echo 0)
  alive=yes; kill -0 "$manager_pid" 2> /dev/null || alive=no
  bench_stop
  row=$(/usr/bin/python3 - "$out/diag_$rate.json" "$rate" "$duration_s" "$rss_kb" "$alive" "$n_frames" <<'PY'
import json, sys
d = json.load(open(sys.argv[1])); rate = float(sys.argv[2]); dur = float(sys.argv[3]); rss = int(sys.argv[4] or 0)
alive = sys.argv[5]; fps = rate * (float(sys.argv[6]) - 1) / dur
odo = next((v for k, v in d.items() if k.endswith(": odometry")), {})
loop = next((v for k, v in d.items() if k.endswith(": loop_detector")), {})
g = lambda m, k: m.get(k, float("nan"))
play_s = dur / rate
kf = g(odo, "keyframes")
lost = g(odo, "dropped_queue_full") + g(odo, "images_not_paired") + g(loop, "dropped_queue_full")
print("| %g | %.1f | %d | %d | %d | %d | %d | %.2f | %d | %d | %.1f / %.1f | %.0f%s |" % (
    rate, fps, g(odo, "images_received"), g(odo, "frames_processed"), g(odo, "dropped_queue_full"),
    g(odo, "images_not_paired"), kf, kf / play_s, g(loop, "dropped_queue_full"),
    g(loop, "local_loops") + g(loop, "global_loops"), g(odo, "ms_per_frame_mean"), g(odo, "ms_per_frame_max"),
    rss / 1024.0, "" if alive == "yes" else " (manager died!)"))
print("NODROP" if lost == 0 and alive == "yes" else "DROP")
PY
) || row="| $rate | (no diagnostics: see $out/launch_$rate.log) |
DROP"
  echo "$row" | head -n 1
  if [ "$(echo "$row" | tail -n 1)" = NODROP ]; then best=$rate; fi
done
echo
echo "Highest rate without a dropped or unpaired frame: ${best:-none} (logs in $out)."
echo
# The per-frame pose while the back-end optimises a 5,000-keyframe map (target <= 100 ms).
/usr/bin/python3 "$UWMS_REPO/scripts/bench_pose_gap.py" --keyframes "${BENCH_POSE_GAP_KEYFRAMES:-5000}" \
  || echo "pose gap: the benchmark failed (see above)"
