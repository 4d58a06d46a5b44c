#!/usr/bin/env bash
# Checks that rviz renders the SLAM outputs for any number of sessions: generates the six-session
# mission (config/missions/six_sessions.yaml: three maps once the joins are made), replays its six
# bags through replay.launch with rviz:=true inside a virtual X server (xvfb-run), and once the
# bags have played takes a screenshot of the screen (ImageMagick's import) into a PNG.
#
#   bash scripts/rviz_snapshot.sh [OUT.png]     # default <repo>/out/rviz/rviz_demo.png
#
# Environment: UWMS_SNAPSHOT_OUT (work directory, default <repo>/out/rviz), UWMS_DEMO_RATE (rosbag
# play rate, default 4), UWMS_SNAPSHOT_SETTLE (seconds between the end of the bags and the
# screenshot, default 5). Everything it started is stopped on exit, failure included.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"

if [ -z "${UWMS_IN_XVFB:-}" ]; then
  bash "$UWMS_REPO/scripts/install_deps.sh"
  bash "$UWMS_REPO/scripts/build.sh"
  # A screen of its own (-a: a free display number), 24-bit for rviz's OpenGL (Mesa, software).
  exec xvfb-run -a -s "-screen 0 1280x800x24 -nolisten tcp" env UWMS_IN_XVFB=1 bash "$0" "$@"
fi

work=${UWMS_SNAPSHOT_OUT:-$UWMS_REPO/out/rviz}
png=${1:-$work/rviz_demo.png}
rate=${UWMS_DEMO_RATE:-4}
settle=${UWMS_SNAPSHOT_SETTLE:-5}
bin="$UWMS_WS/devel/lib/uw_multislam"
set +u
source "$UWMS_WS/devel/setup.bash"
set -u
mkdir -p "$work" "$(dirname "$png")"
echo "[rviz_snapshot] generating the six-session mission into $work/survey (display $DISPLAY)"
rm -rf "$work/survey"
"$bin/make_survey" --config "$UWMS_REPO/config/missions/six_sessions.yaml" --out "$work/survey" --quiet
bags=$(for s in 0 1 2 3 4 5; do printf '%s ' "$work/survey/s$s.bag"; done)

port=$(/usr/bin/python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
export ROS_MASTER_URI="http://127.0.0.1:$port" ROS_HOSTNAME=127.0.0.1
launch_pid=""
cleanup() {
  local status=$? i
  trap - EXIT INT TERM
  if [ -n "$launch_pid" ] && kill -0 "$launch_pid" 2>/dev/null; then
    kill -INT "$launch_pid" 2>/dev/null || true
    for i in $(seq 1 75); do kill -0 "$launch_pid" 2>/dev/null || break; sleep 0.2; done
    kill -KILL "$launch_pid" 2>/dev/null || true
  fi
  [ "$status" -eq 0 ] || echo "[rviz_snapshot] failed (status $status); log: $work/launch.log" >&2
  exit "$status"
}
trap cleanup EXIT
trap 'exit 130' INT
trap 'exit 143' TERM

# roslaunch starts the master (port above), the nodelets, rosbag play and rviz; playing waits for
# the odometry to subscribe, and skip-empty jumps over the day between the missions.
echo "[rviz_snapshot] replay.launch with rviz, rate $rate"
roslaunch -p "$port" uw_multislam replay.launch rviz:=true rate:="$rate" delay:=5 camera_mount:="0 0 0 0" \
  bag:="${bags% }" \
  play_args:="-q --skip-empty=5 --wait-for-subscribers --topics /camera/image_raw /camera/camera_info /altitude" \
  >"$work/launch.log" 2>&1 &
launch_pid=$!

deadline=$(($(date +%s) + 400))
until grep -q "\[player-[0-9]*\] process has finished" "$work/launch.log"; do
  kill -0 "$launch_pid" 2>/dev/null || { echo "[rviz_snapshot] roslaunch stopped:" >&2; tail -n 20 "$work/launch.log" >&2; exit 1; }
  [ "$(date +%s)" -lt "$deadline" ] || { echo "[rviz_snapshot] the bags did not finish in time" >&2; exit 1; }
  sleep 1
done
grep -q "\[rviz-[0-9]*\] process has died" "$work/launch.log" && { echo "[rviz_snapshot] rviz died:" >&2; grep -A3 "rviz" "$work/launch.log" | tail -n 20 >&2; exit 1; }
sleep "$settle"
# A palette PNG keeps the screenshot small (a few hundred kB at most for 1280 x 800).
import -window root "$work/screen_full.png"
convert "$work/screen_full.png" -colors 200 "PNG8:$png"
echo "[rviz_snapshot] screenshot: $png ($(du -k "$png" | cut -f1) kB)"
