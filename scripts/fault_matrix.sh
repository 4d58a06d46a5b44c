#!/usr/bin/env bash
# The fault matrix (issue 21, 6): each fault against offline_slam --db or the live nodelets, one
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
export UWMS_BIN_DIR=${UWMS_BIN_DIR:-$UWMS_WS/devel/lib/uw_multislam}
exec /usr/bin/python3 "$UWMS_REPO/scripts/fault_matrix.py" "$@"
