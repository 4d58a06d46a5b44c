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

# The install space: catkin_make install into <workspace>/install, then test/install/test_install_space.py
# with nothing but install/setup.bash sourced (a clean environment: no devel space, no source tree on any
# path). Its JUnit result joins the others in the summary; a failed install is written as a failed case.
install_xml="$results/uw_multislam/pytest-install_space.xml"
mkdir -p "$(dirname "$install_xml")"
echo "[test] install space: catkin_make install, then its smoke test (log: $UWMS_WS/install.log)"
install_started=$SECONDS
rm -rf "$UWMS_WS/install"  # a fresh install space: files no rule installs any more must not linger
# Configured again in a clean environment: catkin writes the CMAKE_PREFIX_PATH it sees into install/setup.bash,
# and the devel space sourced above must not become an underlay of the install space.
if env -i HOME="${HOME:-$UWMS_WS}" PATH=/usr/bin:/bin LANG=C.UTF-8 \
     catkin_make install --force-cmake -j"${UWMS_JOBS:-$(nproc)}" >"$UWMS_WS/install.log" 2>&1; then
  install_error="the install-space smoke test wrote no result"
  env -i HOME="${HOME:-$UWMS_WS}" PATH=/usr/bin:/bin LANG=C.UTF-8 ROS_HOME="$ROS_HOME" UWMS_INSTALL="$UWMS_WS/install" \
    bash -c 'source "$1/setup.bash" && exec /usr/bin/python3 -m pytest -q -p no:cacheprovider \
      --junitxml="$2" "$3"' - "$UWMS_WS/install" "$install_xml" "$UWMS_REPO/test/install/test_install_space.py" \
    >>"$UWMS_WS/install.log" 2>&1
else
  install_error="catkin_make install failed"
fi
if [ ! -s "$install_xml" ]; then
  cat >"$install_xml" <<XML
<testsuite name="install_space" tests="1" failures="1"><testcase classname="install_space" name="install">
<failure message="$install_error: see $UWMS_WS/install.log"/></testcase></testsuite>
XML
fi
echo "[test] install space done in $((SECONDS - install_started)) s"
/usr/bin/python3 "$UWMS_REPO/scripts/test_summary.py" "$results" --expected "$UWMS_REPO/test/expected_results.txt"
summary_status=$?
if [ $run_status -ne 0 ] && [ $summary_status -eq 0 ]; then
  echo "[test] run_tests itself failed (status $run_status); see $log" >&2
  exit 1
fi
exit $summary_status
