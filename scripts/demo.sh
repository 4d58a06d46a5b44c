#!/usr/bin/env bash
# The demo command: installs what is missing, builds, generates the built-in two-session survey
# (procedural seabed; the second mission dimmer, bluer, turned 90 degrees, a day later) and runs it
# through ROS: a master of its own, the record_run recorder, then replay.launch (nodelets, rosbag
# play --clock on simulated time, no rviz) over both bags. During the run and after it, it calls the
# session services (list_sessions, split_session, join_sessions, one wrong call) and prints the
# answers; the recorder writes the final trajectories in the offline runner's format and
# evaluate.py scores them (metrics table, trajectory plots). Everything it started is stopped on
# exit, failure or Ctrl-C included.
#
#   bash scripts/demo.sh             # through ROS (replay.launch)
#   bash scripts/demo.sh --offline   # offline_slam over the dataset folders, no ROS master
#
# Environment: UWMS_DEMO_OUT (default <repo>/out/demo), UWMS_DEMO_RATE (rosbag play rate, default 4).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"

mode=ros
case "${1:-}" in
  "") ;;
  --offline) mode=offline ;;
  -h | --help) sed -n '2,15p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
  *) echo "demo.sh: unknown option '$1' (use --offline or nothing)" >&2; exit 2 ;;
esac

bash "$UWMS_REPO/scripts/install_deps.sh"
bash "$UWMS_REPO/scripts/build.sh"
bin="$UWMS_WS/devel/lib/uw_multislam"
out=${UWMS_DEMO_OUT:-$UWMS_REPO/out/demo}
rate=${UWMS_DEMO_RATE:-4}
started=$(date +%s)

echo "[demo] generating the two-session demo survey into $out/survey"
"$bin/make_survey" --preset demo --out "$out/survey" --quiet

if [ "$mode" = offline ]; then
  # Its own run and report folders: the ROS demo's (ros_run, report) stay as they are.
  rm -rf "$out/offline_run" "$out/offline_report"
  echo "[demo] offline_slam over both sessions into $out/offline_run"
  "$bin/offline_slam" --session "$out/survey/s0" --session "$out/survey/s1" --out "$out/offline_run"
  echo "[demo] scoring the run against the ground truth"
  /usr/bin/python3 "$UWMS_REPO/src/tools/evaluate.py" --run "$out/offline_run" --mission "$out/survey" \
    --report "$out/offline_report" --html
  echo "[demo] done in $(($(date +%s) - started)) s: survey in $out/survey, run in $out/offline_run,"
  echo "[demo] metrics, plots and report.html (one self-contained page) in $out/offline_report"
  exit 0
fi

# ---- through ROS ---------------------------------------------------------------------------
set +u
source "$UWMS_WS/devel/setup.bash"
set -u
logs="$out/ros"
run="$out/ros_run"
rm -rf "$logs" "$run" "$out/report"
mkdir -p "$logs"
# A master of our own on a free port: never talk to (or stop) someone else's.
port=$(/usr/bin/python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
export ROS_MASTER_URI="http://127.0.0.1:$port" ROS_HOSTNAME=127.0.0.1

core_pid="" recorder_pid="" launch_pid=""
stop() {  # stop PID: SIGINT (ROS shuts down cleanly), then SIGTERM, then SIGKILL
  local pid=$1 i
  [ -n "$pid" ] && kill -0 "$pid" 2>/dev/null || return 0
  kill -INT "$pid" 2>/dev/null || true
  for i in $(seq 1 50); do kill -0 "$pid" 2>/dev/null || return 0; sleep 0.2; done
  kill -TERM "$pid" 2>/dev/null || true
  for i in $(seq 1 25); do kill -0 "$pid" 2>/dev/null || return 0; sleep 0.2; done
  kill -KILL "$pid" 2>/dev/null || true
}
cleanup() {
  local status=$?
  trap - EXIT INT TERM
  stop "$recorder_pid"
  stop "$launch_pid"
  stop "$core_pid"
  if [ "$status" -ne 0 ]; then
    echo "[demo] failed (status $status); logs in $logs (launch.log, recorder.log, roscore.log)" >&2
  fi
  exit "$status"
}
trap cleanup EXIT
trap 'exit 130' INT
trap 'exit 143' TERM

sessions() { /usr/bin/python3 "$UWMS_REPO/src/tools/sessions.py" "$@"; }
wait_for() {  # wait_for SECONDS DESCRIPTION COMMAND...: polls COMMAND every 0.5 s
  local deadline=$(($(date +%s) + $1)) what=$2
  shift 2
  until "$@" >/dev/null 2>&1; do
    if [ "$(date +%s)" -ge "$deadline" ]; then echo "[demo] timed out waiting for $what" >&2; return 1; fi
    sleep 0.5
  done
}
master_up() { /usr/bin/python3 -c 'import rosgraph, sys; sys.exit(0 if rosgraph.is_master_online() else 1)'; }

echo "[demo] ROS master on $ROS_MASTER_URI (logs in $logs)"
roscore -p "$port" >"$logs/roscore.log" 2>&1 &
core_pid=$!
wait_for 30 "the ROS master" master_up

# A fresh session store for this run (the back-end writes every keyframe, loop and join to it).
rm -f "$out/sessions.db" "$out/sessions.db-wal" "$out/sessions.db-shm"

/usr/bin/python3 "$UWMS_REPO/src/tools/record_run.py" --out "$run" \
  --session-dir "$out/survey/s0" --session-dir "$out/survey/s1" --ready-file "$logs/recorder.ready" \
  >"$logs/recorder.log" 2>&1 &
recorder_pid=$!
wait_for 30 "the recorder" test -e "$logs/recorder.ready"

# Both bags in one rosbag play, merged by stamp; skip-empty jumps over the day between the
# missions (the odometry starts session 1 at the stamp gap); playing waits for the odometry.
echo "[demo] replay.launch: s0.bag then s1.bag at rate $rate on simulated time, rviz off"
roslaunch uw_multislam replay.launch rviz:=false stay_up:=true rate:="$rate" store_path:="$out/sessions.db" \
  camera_mount:="0 0 0 0" \
  bag:="$out/survey/s0.bag $out/survey/s1.bag" \
  play_args:="-q --skip-empty=5 --wait-for-subscribers --topics /camera/image_raw /camera/camera_info /altitude" \
  >"$logs/launch.log" 2>&1 &
launch_pid=$!
player_done() { grep -q "\[player-[0-9]*\] process has finished" "$logs/launch.log"; }
launch_alive() { kill -0 "$launch_pid" 2>/dev/null; }

# During the run: once session 1 has begun, the state of the sessions.
wait_for 300 "session 1 to start" grep -q "session 1: first keyframe" "$logs/recorder.log"
echo "[demo] session 1 started (t = $(($(date +%s) - started)) s):"
sleep 3
sessions list
wait_for 300 "the bags to finish" player_done
launch_alive || { echo "[demo] replay.launch stopped early:" >&2; tail -n 20 "$logs/launch.log" >&2; exit 1; }
sleep 4  # the last keyframes and loops through the back-end
echo "[demo] bags played (t = $(($(date +%s) - started)) s); the sessions now:"
sessions list
echo "[demo] split session 1 off its map, then join the two again (min_loops 0: the configured join rule):"
sessions split 1
sessions list
sessions join 0 1 0
echo "[demo] a wrong call answers with a status and changes nothing:"
sessions join 0 42 0 || echo "[demo] sessions.py exit status $?: refused"
sessions list
sleep 2  # the republished (latched) paths reach the recorder

echo "[demo] recording the final trajectories into $run"
kill -INT "$recorder_pid"
wait "$recorder_pid" || { echo "[demo] the recorder failed:" >&2; tail -n 20 "$logs/recorder.log" >&2; exit 1; }
recorder_pid=""
grep "^\[record_run\] [0-9]* sessions" "$logs/recorder.log"
stop "$launch_pid"
launch_pid=""
stop "$core_pid"
core_pid=""

echo "[demo] scoring the run against the ground truth"
/usr/bin/python3 "$UWMS_REPO/src/tools/evaluate.py" --run "$run" --mission "$out/survey" --report "$out/report" --html
echo "[demo] done in $(($(date +%s) - started)) s: survey in $out/survey, ROS run in $run (logs in $logs),"
echo "[demo] metrics, trajectory plots (map_0.png, session_<s>.png) and report.html in $out/report"
