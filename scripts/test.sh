#!/usr/bin/env bash
# The test command: installs what is missing, builds with warnings as errors, builds the install
# space, runs every suite (gtest, pytest, rostest, launch checks, the fault matrix, the tutorial, the
# format check, the install-space smoke test), prints one summary with the failures. Exit status 0
# only when everything built and every expected suite ran and passed.
#
# The suites run UWMS_TEST_JOBS at a time (default 3): ctest runs the ones CMakeLists.txt registers,
# each with a ROS_HOME of its own (a rostest starts its own master on a free port); the gtests are
# compiled meanwhile, as one of them. UWMS_TEST_DEBUG_INFO=0 (CI's .ci/run) compiles without -g: the
# same machine code (GCC's -g changes none), a third less compile time. Each step's wall and CPU time
# is printed; doc/benchmarks/ci.md has the measured ones.
set -uo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"

# CPU seconds (user + system) of the finished children of this shell: on a machine that others load
# too, a step's CPU time says more than its wall time.
ticks=$(getconf CLK_TCK)
children_cpu() { awk -v t="$ticks" '{ printf "%d", ($16 + $17) / t }' "/proc/$$/stat"; }
step_started=$SECONDS
step_cpu=$(children_cpu)
step_done() {  # $1: what was done; prints its duration and starts the next step's clock
  local cpu
  cpu=$(children_cpu)
  echo "[test] $1 in $((SECONDS - step_started)) s (CPU $((cpu - step_cpu)) s, load $(cut -d' ' -f1 /proc/loadavg))"
  step_started=$SECONDS
  step_cpu=$cpu
}

bash "$UWMS_REPO/scripts/install_deps.sh" || { echo "[test] dependency installation failed" >&2; exit 1; }
step_done "dependencies"
# The flags of the default RelWithDebInfo build given either way, so that a workspace that once ran
# without -g does not keep that (CMake caches them). CMake's own default for GCC: -O2 -g -DNDEBUG.
release_flags="-O2 -g -DNDEBUG"
if [ "${UWMS_TEST_DEBUG_INFO:-1}" = 0 ]; then release_flags="-O2 -DNDEBUG"; fi
bash "$UWMS_REPO/scripts/build.sh" -DUWMS_WERROR=ON -DCATKIN_ENABLE_TESTING=ON \
  "-DCMAKE_CXX_FLAGS_RELWITHDEBINFO=$release_flags" || exit 1
step_done "build"

cd "$UWMS_WS" || exit 1
# shellcheck disable=SC1091
set +u
source devel/setup.bash
set -u
results="$UWMS_WS/build/test_results"
rm -rf "$results" "$UWMS_WS/build/test_ros_home"
log="$UWMS_WS/test.log"

# The install space: catkin_make install into <workspace>/install, then test/install/test_install_space.py
# with nothing but install/setup.bash sourced (a clean environment: no devel space, no source tree on any
# path). Its JUnit result joins the others in the summary; a failed install is written as a failed case.
# Before the suites: it configures the build directory again, which must not happen while they run
# (nothing is compiled again: the targets are up to date). Its smoke test then runs beside them.
# (catkin_make install does not build the gtests: ctest does, below.)
install_xml="$results/uw_multislam/pytest-install_space.xml"
install_log="$UWMS_WS/install.log"
mkdir -p "$(dirname "$install_xml")"
echo "[test] install space: catkin_make install (log: $install_log)"
rm -rf "$UWMS_WS/install"  # a fresh install space: files no rule installs any more must not linger
# Configured again in a clean environment: catkin writes the CMAKE_PREFIX_PATH it sees into install/setup.bash,
# and the devel space sourced above must not become an underlay of the install space.
install_pid=""
if env -i HOME="${HOME:-$UWMS_WS}" PATH=/usr/bin:/bin LANG=C.UTF-8 \
     catkin_make install --force-cmake -j"${UWMS_JOBS:-$(nproc)}" >"$install_log" 2>&1; then
  install_error="the install-space smoke test wrote no result"
  mkdir -p "$UWMS_WS/build/test_ros_home/install_space"
  env -i HOME="${HOME:-$UWMS_WS}" PATH=/usr/bin:/bin LANG=C.UTF-8 ROS_HOME="$UWMS_WS/build/test_ros_home/install_space" \
    UWMS_INSTALL="$UWMS_WS/install" \
    bash -c 'source "$1/setup.bash" && exec /usr/bin/python3 -m pytest -q -p no:cacheprovider \
      --junitxml="$2" "$3"' - "$UWMS_WS/install" "$install_xml" "$UWMS_REPO/test/install/test_install_space.py" \
    >>"$install_log" 2>&1 &
  install_pid=$!
else
  install_error="catkin_make install failed"
fi
step_done "install space installed"

jobs=${UWMS_TEST_JOBS:-3}
echo "[test] running the suites, $jobs at a time, and building the gtests (log: $log; each suite's output:"\
  "$UWMS_WS/build/Testing/Temporary/LastTest.log)"
# --timeout: a hung suite is stopped (its missing or failed result then fails the summary); the longest,
# the fault matrix, takes about 6 minutes on a loaded machine. The gtests' build (the ctest test
# uwms_build_tests) compiles with UWMS_JOBS jobs.
CMAKE_BUILD_PARALLEL_LEVEL=${UWMS_JOBS:-$(nproc)} \
  ctest --test-dir "$UWMS_WS/build" -j"$jobs" --timeout 900 --no-tests=error --output-on-failure 2>&1 |
  tee "$log" | grep --line-buffered -E "^ *[0-9]+/[0-9]+ Test +#" | sed -u -e 's/_ctest_uw_multislam_//' -e 's/ \.\.\.*/ /'
run_status=${PIPESTATUS[0]}
if ! grep -qE "Test +#[0-9]+: uwms_build_tests \.* +Passed" "$log"; then
  echo "[test] building the gtests FAILED ($UWMS_WS/build/tests_build.log):" >&2
  grep -E "error|Error" "$UWMS_WS/build/tests_build.log" 2>/dev/null | head -n 60 >&2 ||
    tail -n 60 "$UWMS_WS/build/tests_build.log" >&2
fi
if [ -n "$install_pid" ]; then
  wait "$install_pid"
fi
if [ ! -s "$install_xml" ]; then
  cat >"$install_xml" <<XML
<testsuite name="install_space" tests="1" failures="1"><testcase classname="install_space" name="install">
<failure message="$install_error: see $install_log"/></testcase></testsuite>
XML
fi
step_done "suites run"
/usr/bin/python3 "$UWMS_REPO/scripts/test_summary.py" "$results" --expected "$UWMS_REPO/test/expected_results.txt"
summary_status=$?
if [ "$run_status" -ne 0 ] && [ "$summary_status" -eq 0 ]; then
  echo "[test] ctest itself failed (status $run_status); see $log" >&2
  exit 1
fi
exit $summary_status
