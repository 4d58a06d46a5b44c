#!/usr/bin/env bash
# Load sweep (scripts/bench_load_sweep.sh): a generated mission bag replayed through slam.launch (nodelet manager,
# default queues) at increasing rates. For each rate a fresh pipeline; at the end the counters are
# read from /diagnostics (scripts/diagnostics_snapshot.py) and the nodelet manager's peak RSS
# (VmHWM) from /proc. Prints one markdown table and the highest rate held without a dropped or
# unpaired frame; then the longest gap in the back-end's current pose during an optimisation of
# a 5,000-keyframe map (scripts/bench_pose_gap.py). Not a test: numbers for this machine.
# usage: scripts/bench_load_sweep.sh [--rates "1 2 5 10 20 40 80 160"] [--preset NAME] [--prepare-threads N] [OUT_DIR]
#   default mission: make_survey --preset demo, session s0 (its bag); rates 1 2 5 10 20 40 80 160.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
rates="1 2 5 10 20 40 80 160"
preset=demo
prepare_threads=0  # the odometry nodelet's ~prepare_threads (a second core preparing waiting frames)
while [ $# -gt 0 ]; do
  case "$1" in
    --rates) rates=$2; shift 2 ;;
    --preset) preset=$2; shift 2 ;;
    --prepare-threads) prepare_threads=$2; shift 2 ;;
    *) break ;;
  esac
done
out=${1:-$(mktemp -d /tmp/uwms_bench_load.XXXXXX)}
mkdir -p "$out"
bin="$UWMS_WS/devel/lib/uw_multislam"
[ -x "$bin/make_survey" ] || { echo "bench_load_sweep: build first (scripts/build.sh)" >&2; exit 1; }
# The ROS-side parameters with the odometry's prepare_threads set (slam.launch config:=).
grep -q '^  prepare_threads: 0$' "$UWMS_REPO/config/default.yaml" || { echo "bench_load_sweep: prepare_threads not in config/default.yaml" >&2; exit 1; }
# prepare_threads > 0 needs drop_policy oldest (frames prepared in the order they wait).
policy=newest; [ "$prepare_threads" -gt 0 ] && policy=oldest
sed -e "s/^  prepare_threads: 0$/  prepare_threads: $prepare_threads/" -e "s/^  drop_policy: newest$/  drop_policy: $policy/" \
  "$UWMS_REPO/config/default.yaml" > "$out/default.yaml"
set +u; source "$UWMS_WS/devel/setup.bash"; set -u
export ROS_MASTER_URI=${BENCH_MASTER_URI:-http://localhost:11391}  # a master of its own
log() { echo "[bench_load_sweep] $*" >&2; }

[ -d "$out/mission" ] || { log "make_survey --preset $preset"; "$bin/make_survey" --preset "$preset" --out "$out/mission" --quiet > /dev/null; }
bag="$out/mission/s0.bag"
frames=$(/usr/bin/python3 -c 'import rosbag,sys; b=rosbag.Bag(sys.argv[1]); print(b.get_message_count("/camera/image_raw")); print(b.get_end_time()-b.get_start_time())' "$bag" | paste -sd' ')
read -r n_frames duration_s <<< "$frames"
log "bag: $n_frames frames over $duration_s s"

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

echo "### Load: $(basename "$bag") ($n_frames frames, $(printf %.0f "$duration_s") s) through slam.launch (odometry prepare_threads $prepare_threads, drop_policy $policy), $(date -u +%F), $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), $(nproc) cores"
echo
echo "| rate | frames/s offered | images received | processed | dropped (odometry queue) | not paired | keyframes | keyframes/s | loop detector dropped | loops | odometry ms/frame mean / max | manager peak RSS MB |"
echo "|---|---|---|---|---|---|---|---|---|---|---|---|"
best=""
for rate in $rates; do
  rosparam delete /uw_multislam > /dev/null 2>&1 || true
  # A fresh pipeline per rate: no session store, so nothing carries over from the last rate.
  roslaunch uw_multislam slam.launch store_path:=none camera_mount:="0 0 0 0" config:="$out/default.yaml" > "$out/launch_$rate.log" 2>&1 &
  launch_pid=$!
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
  kill -INT "$launch_pid" 2> /dev/null || true
  wait "$launch_pid" 2> /dev/null || true
  launch_pid=""
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
