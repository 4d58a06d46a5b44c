# Set-up shared by scripts/bench_load.sh and scripts/bench_load_sweep.sh. Sourced, not run.
#   bench_init NAME DEFAULT_PORT [OUT_DIR]  out (made), bin, log(), ROS_MASTER_URI (BENCH_MASTER_URI or
#                                            the port: a master of its own), the workspace's setup.bash
#   bench_config FILE [NODE/]KEY=VALUE...   config/default.yaml with the keys set (NODE: odometry_node by
#                                            default; each checked: a renamed key stops the bench)
#   bench_roscore                           starts the master; on exit it and any launch are stopped
#   bench_launch LOG CONFIG                 slam.launch (one nodelet manager, no store) in the background
#   bench_stop                              stops that launch
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"

bench_init() {
  bench_name=$1
  out=${3:-$(mktemp -d /tmp/uwms_bench_load.XXXXXX)}
  mkdir -p "$out"
  bin="$UWMS_WS/devel/lib/uw_multislam"
  [ -x "$bin/make_survey" ] || { echo "$bench_name: build first (scripts/build.sh)" >&2; exit 1; }
  set +u; source "$UWMS_WS/devel/setup.bash"; set -u
  export ROS_MASTER_URI=${BENCH_MASTER_URI:-http://localhost:$2}
}

log() { echo "[$bench_name] $*" >&2; }

bench_config() {  # FILE [NODE/]KEY=VALUE...: keys of config/default.yaml's NODE: section (default odometry_node)
  local f=$1 kv key value node section
  shift
  cp "$UWMS_REPO/config/default.yaml" "$f"
  for kv in "$@"; do
    key=${kv%%=*} value=${kv#*=} node=odometry_node
    case "$key" in */*) node=${key%%/*} key=${key#*/} ;; esac
    # Only inside the node's section (other nodes have a queue_size too).
    section=$(awk -v k="$key" -v n="$node:" '/^[a-z_]+:/ { s = $1 } s == n && $0 ~ "^  " k ":" { print NR; exit }' "$f")
    [ -n "$section" ] || { echo "$bench_name: $node/$key not found in config/default.yaml" >&2; exit 1; }
    sed -i "${section}s/^  $key: .*/  $key: $value/" "$f"
  done
}

launch_pid=""
bench_roscore() {
  roscore -p "${ROS_MASTER_URI##*:}" > "$out/roscore.log" 2>&1 &
  core_pid=$!
  trap bench_cleanup EXIT
  for _ in $(seq 50); do rostopic list > /dev/null 2>&1 && break; sleep 0.2; done
}
bench_cleanup() {
  bench_stop
  kill -INT "$core_pid" 2> /dev/null && wait "$core_pid" 2> /dev/null || true
}

bench_launch() {  # LOG CONFIG: a fresh pipeline, nothing carried over from the last run (no store)
  rosparam delete /uw_multislam > /dev/null 2>&1 || true
  roslaunch uw_multislam slam.launch store_path:=none camera_mount:="0 0 0 0" config:="$2" > "$1" 2>&1 &
  launch_pid=$!
}
bench_stop() {
  [ -n "$launch_pid" ] && kill -INT "$launch_pid" 2> /dev/null && wait "$launch_pid" 2> /dev/null || true
  launch_pid=""
}
