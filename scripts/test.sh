#!/usr/bin/env bash
# The test command: installs what is missing, builds with warnings as errors, runs every gtest
# and rostest, prints one summary with the failures. Exit status 0 only when everything built
# and every test passed.
set -uo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"

bash "$UWMS_REPO/scripts/install_deps.sh" || { echo "[test] dependency installation failed" >&2; exit 1; }
bash "$UWMS_REPO/scripts/build.sh" -DUWMS_WERROR=ON -DCATKIN_ENABLE_TESTING=ON || exit 1

cd "$UWMS_WS"
# shellcheck disable=SC1091
set +u
source devel/setup.bash
set -u
results="$UWMS_WS/build/test_results"
rm -rf "$results"
log="$UWMS_WS/test.log"
echo "[test] building tests"
if ! catkin_make tests -j"${UWMS_JOBS:-$(nproc)}" >"$log" 2>&1; then
  echo "[test] building the tests FAILED:" >&2
  grep -E "error|Error" "$log" | head -n 60 >&2 || tail -n 60 "$log" >&2
  exit 1
fi
echo "[test] running gtests and rostests (log: $log)"
# -j1: rostests start their own master; running them one at a time keeps ports and CPU free.
catkin_make run_tests -j1 >>"$log" 2>&1
run_status=$?
/usr/bin/python3 "$UWMS_REPO/scripts/test_summary.py" "$results"
summary_status=$?
if [ $run_status -ne 0 ] && [ $summary_status -eq 0 ]; then
  echo "[test] run_tests itself failed (status $run_status); see $log" >&2
  exit 1
fi
exit $summary_status
