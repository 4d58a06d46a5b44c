#!/usr/bin/env bash
# Builds uw_multislam with catkin_make. Extra arguments go to CMake, e.g. -DUWMS_WERROR=ON.
# Environment: UWMS_WS (workspace, default <repo>_ws beside the repository), UWMS_BUILD_TYPE (default
# RelWithDebInfo), UWMS_JOBS (default: number of cores).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"

# A workspace inside the repository makes rosrun find every tool several times (common.sh).
ws_real=$(realpath -m "$UWMS_WS")
for ws in "$ws_real" "$UWMS_REPO/.catkin_ws"; do
  if [[ "$ws/" == "$UWMS_REPO"/* ]] && [[ "$ws" == "$ws_real" || ( -e "$ws" && "$ws" != "$ws_real" ) ]]; then
    echo "[build] warning: $ws is a workspace inside the repository: rosrun finds each tool in it again" \
      "('non-unique executable'); remove it (rm -rf $ws) and build beside the repository (UWMS_WS)" >&2
  fi
done

mkdir -p "$UWMS_WS/src"
ln -sfn "$UWMS_REPO" "$UWMS_WS/src/uw_multislam"
cd "$UWMS_WS"
jobs=${UWMS_JOBS:-$(nproc)}
log="$UWMS_WS/build.log"
echo "[build] catkin_make in $UWMS_WS (log: $log)"
if ! catkin_make -DPYTHON_EXECUTABLE=/usr/bin/python3 -DCMAKE_BUILD_TYPE="${UWMS_BUILD_TYPE:-RelWithDebInfo}" \
     "$@" -j"$jobs" >"$log" 2>&1; then
  echo "[build] FAILED; the errors:" >&2
  grep -E "error|Error|FAILED|warning" "$log" | head -n 60 >&2 || tail -n 60 "$log" >&2
  exit 1
fi
warnings=$(grep -c "warning:" "$log" || true)
echo "[build] ok ($warnings compiler warnings)"
