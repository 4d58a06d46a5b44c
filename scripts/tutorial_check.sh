#!/usr/bin/env bash
# Follows doc/tutorial.md literally: runs its ```bash blocks, in order, in one bash shell (errexit,
# pipefail) in a fresh empty directory, with a ROS master of its own on a free port; then checks
# what the tutorial promises: the practice bag's unusual topic names in `rosbag info`, a run with
# both dives as sessions 0 and 1 and every keyframe placed in its folder, and a report scoring
# both sessions.
#
#   bash scripts/tutorial_check.sh [--junit FILE] [--keep]
#
# Needs the package built (the workspace's setup.bash is sourced unless rospack already finds
# uw_multislam). --junit writes the result as JUnit XML (catkin run_tests does, so scripts/test.sh
# counts it); --keep leaves the working directory. Exit status 0 when every check passed.
set -uo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"

junit="" keep=false
while [ $# -gt 0 ]; do
  case "$1" in
    --junit) junit=$2; shift 2 ;;
    --keep) keep=true; shift ;;
    -h | --help) sed -n '2,13p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "tutorial_check.sh: unknown argument '$1'" >&2; exit 2 ;;
  esac
done
if ! rospack find uw_multislam >/dev/null 2>&1; then
  set +u
  # shellcheck disable=SC1091
  source "$UWMS_WS/devel/setup.bash"
  set -u
fi

tutorial="$UWMS_REPO/doc/tutorial.md"
work=$(mktemp -d /tmp/uwms_tutorial.XXXXXX)
log="$work/tutorial.log"
started=$(date +%s)
failures=()
fail() { failures+=("$1"); echo "[tutorial] FAILED: $1" >&2; }

# The ```bash blocks, as written, after a header that stops at the first failing command.
{
  echo "set -eo pipefail"
  awk '/^```bash[[:space:]]*$/ { inside = 1; next } /^```/ { inside = 0; next } inside' "$tutorial"
} >"$work/tutorial.sh"
echo "[tutorial] $(grep -c '^```bash' "$tutorial") bash blocks of $tutorial -> $work/tutorial.sh"

# Its own master (the tutorial's roscore takes the port of ROS_MASTER_URI), logs in the work dir.
port=$(/usr/bin/python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
export ROS_MASTER_URI="http://127.0.0.1:$port" ROS_HOSTNAME=127.0.0.1 ROS_HOME="$work/ros_home"
export ROS_LOG_DIR="$ROS_HOME/log"
mkdir -p "$work/tutorial"

# In a session of its own: on a failure or a timeout, everything it started is stopped by group.
(cd "$work/tutorial" && exec setsid timeout -s INT -k 20 240 bash "$work/tutorial.sh") >"$log" 2>&1 &
pid=$!
wait "$pid"
status=$?
if kill -0 -- "-$pid" 2>/dev/null; then
  kill -INT -- "-$pid" 2>/dev/null
  for _ in $(seq 1 40); do kill -0 -- "-$pid" 2>/dev/null || break; sleep 0.25; done
  kill -KILL -- "-$pid" 2>/dev/null
fi
[ "$status" -eq 0 ] || fail "the tutorial's commands stopped with status $status (last lines of $log below)"

dir="$work/tutorial"
for topic in /rov/cam_down/image_mono /rov/cam_down/info /rov/dvl/altitude; do
  grep -qE "$topic +[0-9]+ msgs +: sensor_msgs/" "$log" || fail "rosbag info did not show $topic"
done
placed=$(grep -o "^\[record_run\] [0-9]* sessions.*" "$log" | tail -n 1)
echo "[tutorial] recorder: ${placed:-no summary line}"
echo "$placed" | grep -q "; 0 keyframes not placed by stamp" || fail "record_run left keyframes unplaced: $placed"
if [ -f "$dir/run/odometry.csv" ]; then
  sessions=$(awk -F, 'NR > 1 { print $1 }' "$dir/run/odometry.csv" | sort -u | tr '\n' ' ')
  [ "$sessions" = "0 1 " ] || fail "run/odometry.csv has sessions '$sessions', expected '0 1 '"
  [ -f "$dir/run/inputs.csv" ] || fail "no run/inputs.csv"
else
  fail "no run/odometry.csv"
fi
if [ -f "$dir/report/metrics.md" ]; then
  for row in "| 0 | odometry |" "| 0 | slam |" "| 1 | odometry |" "| 1 | slam |"; do
    grep -qF "$row" "$dir/report/metrics.md" || fail "report/metrics.md has no row '$row'"
  done
  [ -f "$dir/report/map_0.png" ] || fail "no report/map_0.png"
  echo "[tutorial] report/metrics.md sessions:"
  grep -E "^\| [01] \| (odometry|slam) \|" "$dir/report/metrics.md"
else
  fail "no report/metrics.md"
fi
elapsed=$(($(date +%s) - started))

if [ ${#failures[@]} -gt 0 ]; then
  echo "[tutorial] last lines of $log:" >&2
  tail -n 25 "$log" >&2
fi
if [ -n "$junit" ]; then
  mkdir -p "$(dirname "$junit")"
  /usr/bin/python3 - "$junit" "$elapsed" "${failures[@]}" <<'EOF'
import sys
from xml.sax.saxutils import escape, quoteattr
path, seconds, failures = sys.argv[1], sys.argv[2], sys.argv[3:]
case = '<testcase classname="tutorial" name="doc_tutorial_md" time="%s">' % seconds
if failures:
    case += '<failure message=%s>%s</failure>' % (quoteattr(failures[0]), escape("\n".join(failures)))
case += "</testcase>"
with open(path, "w") as f:
    f.write('<?xml version="1.0" encoding="UTF-8"?>\n<testsuite name="tutorial" tests="1" failures="%d" '
            'errors="0" skipped="0" time="%s">%s</testsuite>\n' % (1 if failures else 0, seconds, case))
EOF
fi
if [ ${#failures[@]} -gt 0 ]; then
  echo "[tutorial] FAILED (${#failures[@]} check(s), $elapsed s); kept $work" >&2
  exit 1
fi
echo "[tutorial] passed in $elapsed s"
$keep || rm -rf "$work"
exit 0
