#!/usr/bin/env bash
# The fault matrix: each fault against offline_slam --db or the live nodelets, one
# markdown table row per case (case, expected, observed, verdict) and "N of M held" at the end.
# Exit status 0 only when every case held. Options are fault_matrix.py's:
#
#   bash scripts/fault_matrix.sh [--only SUBSTRING ...] [--offline] [--junit FILE] [--keep]
#
# Needs the package built; sources the workspace's setup.bash (UWMS_WS, as scripts/common.sh).
set -uo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
case "${1:-}" in -h | --help) sed -n '2,8p' "$0" | sed 's/^# \{0,1\}//'; exec /usr/bin/python3 "$UWMS_REPO/scripts/fault_matrix.py" --help ;; esac
if ! rospack find uw_multislam >/dev/null 2>&1; then
  set +u
  # shellcheck disable=SC1091
  source "$UWMS_WS/devel/setup.bash"
  set -u
fi
# The tools of the package found first on ROS's paths (the sourced workspace's), unless given.
if [ -z "${UWMS_BIN_DIR:-}" ]; then
  tool=$(catkin_find --first-only --libexec uw_multislam offline_slam 2>/dev/null || true)
  UWMS_BIN_DIR=$(dirname "${tool:-$UWMS_WS/devel/lib/uw_multislam/offline_slam}")
fi
export UWMS_BIN_DIR
exec /usr/bin/python3 "$UWMS_REPO/scripts/fault_matrix.py" "$@"
