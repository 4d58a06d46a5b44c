#!/usr/bin/env bash
# Platform check: builds uw_multislam against Debian 11 (bullseye), the nearest this machine can reach
# to the platforms users run (Ubuntu 20.04 with ROS Noetic; JetPack 5, Ubuntu 20.04 arm64): GCC 10
# (and GCC 9, Ubuntu 20.04's), OpenCV 4.5.1, GDAL 3.2 (no CMake config file: FindGDAL), Ceres 1.14,
# CMake 3.18, Boost 1.74, Eigen 3.3, VLFeat 0.9.21 (amd64 only) and Debian's ROS 1 packages. Runs the
# gtests there and prints their counts. Not part of CI (an hour or more per architecture).
#
# The roots come from scripts/debian_root.sh (debootstrap, mounts, apt-get inside), as arm64_check.sh's.
#
#   amd64: a bullseye amd64 root (debootstrap --variant=minbase); in it, with its own compilers:
#     1. the whole package with catkin_make (every node and tool, and every gtest: make tests) when
#        every ROS -dev package it needs is in bullseye (else the ROS-free core, the simulator and
#        test_core with plain CMake, scripts/arm64/CMakeLists.txt, and the missing packages named);
#        then test_core and, for the whole package, the ROS-free gtests (test_conversions,
#        test_no_gdal, test_work_queue, test_dataset_bag) and a few rostests;
#     2. the core, the simulator and test_core again with g++-9 and -DUWMS_FORCE_SIFT_BACKEND=vlfeat:
#        Ubuntu 20.04's compiler, and its OpenCV 4.2 that has no SIFT (VLFeat's instead).
#   arm64: as scripts/arm64_check.sh does for Debian 12: a bullseye arm64 root (debootstrap, second
#     stage under qemu-user through binfmt_misc) holds the arm64 -dev libraries; the cross compiler
#     of bullseye (aarch64-linux-gnu-g++ 10, installed in the amd64 root, where the arm64 root is
#     bind-mounted as /sysroot) builds the core, the simulator and test_core; qemu-aarch64-static
#     runs test_core. (Debian has no arm64 VLFeat: OpenCV's SIFT only.)
#
# usage: sudo scripts/platform_check.sh amd64|arm64 [gtest arguments, e.g. --gtest_filter=Iekf.*]
#   UWMS_PLATFORM_ROOT    folder of the roots and builds (default <repo>_platform beside the repository:
#                         bullseye-amd64/, bullseye-arm64/, logs)
#   UWMS_PLATFORM_JOBS    compile jobs (default 1: the machine is shared)
#   UWMS_PLATFORM_MIRROR  Debian mirror (default: the one the host's apt uses for its own suite)
#   UWMS_ROOT_SETUP_ONLY  1: set the roots up (debootstrap, apt-get; scripts/debian_root.sh) and stop
#   UWMS_PLATFORM_ROSTESTS amd64 whole package only: the rostests run in the root (default core_launch.test
#                         datum.test slam_pipeline.test sensor_frames.test dvl_altitude.test
#                         backend_services.test, about 2 min; empty: none)
#   UWMS_PLATFORM_PACKAGE amd64 only: 0 skips step 1 (the package with GCC 10, an hour or more at -j1 from
#                         nothing) and runs step 2 alone (default 1)
# Idempotent and incremental: a second run reuses the roots and the builds. The repository is
# bind-mounted read-only into the amd64 root at its own path. Prints, last, one line per build:
# "platform_check: <what>: N tests passed, M failed (...), build X s, run Y s"; exits non-zero when
# a build or a test fails.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
source "$(dirname "${BASH_SOURCE[0]}")/debian_root.sh"
ARCH=${1:-}
case "$ARCH" in amd64 | arm64) shift ;; *) echo "usage: sudo $0 amd64|arm64 [gtest arguments]" >&2; exit 2 ;; esac
DIR=${UWMS_PLATFORM_ROOT:-$(dirname "$UWMS_REPO")/$(basename "$UWMS_REPO")_platform}
SUITE=bullseye
AMD=$DIR/$SUITE-amd64
ARM=$DIR/$SUITE-arm64
JOBS=${UWMS_PLATFORM_JOBS:-1}
ROSTESTS=${UWMS_PLATFORM_ROSTESTS-core_launch.test datum.test slam_pipeline.test sensor_frames.test dvl_altitude.test
backend_services.test}
log() { echo "[platform_check] $*" >&2; }
die() { log "$*"; exit 1; }
[ "$(id -u)" -eq 0 ] || die "needs root (debootstrap, chroot, mount): run it with sudo"
case "$DIR" in "$UWMS_REPO" | "$UWMS_REPO"/*) die "UWMS_PLATFORM_ROOT=$DIR is inside the repository" ;; esac
mkdir -p "$DIR"
t_start=$SECONDS

# --- host tools; the roots (scripts/debian_root.sh) from the host's Debian archive, the only one
# reachable here; everything mounted below them comes down on exit, error or ^C -----------------------
if [ "$ARCH" = arm64 ]; then
  host_install "$DIR/host_apt.log" debootstrap python3 qemu-user-static binfmt-support
  binfmt_arm64 > /dev/null
else
  host_install "$DIR/host_apt.log" debootstrap python3
fi
MIRROR=${UWMS_PLATFORM_MIRROR:-$(host_uri $SUITE)}
trap 'unmount_below "$DIR"' EXIT
{
  echo "deb $MIRROR $SUITE main"
  echo "deb $MIRROR $SUITE-updates main"
  # No $SUITE-security: a build check needs no security fixes, and the archive this machine reaches
  # lists bullseye-security packages it does not serve (404).
} > "$DIR/sources.list"

# unavailable ROOT PACKAGES... -> the names apt in ROOT has no candidate for (unknown, or only
# named by other packages), one a line
unavailable() {
  local root=$1 p; shift
  # Not "| grep -q": it may close the pipe before apt-cache ends, whose SIGPIPE pipefail reports.
  for p in "$@"; do [[ "$(in_root "$root" apt-cache policy "$p" 2>/dev/null)" == *"Candidate: "[^\(]* ]] || echo "$p"; done
}

# --- gtest runs, counted by scripts/debian_root.sh (skipped and disabled tests count neither way) ----
summary=()
status=0
# run_gtest WHAT XML LOG COMMAND...: runs one gtest binary, counts it from its XML (or its log if it died)
run_gtest() {
  local what=$1 xml=$2 logf=$3 t0=$SECONDS rc passed failed; shift 3
  rm -f "$xml"
  log "$what (log: $logf)"
  set +e
  "$@" > "$logf" 2>&1
  rc=$?
  set -e
  read -r passed failed < <(gtest_counts "$xml" "$logf")
  if [ "$rc" -ne 0 ] && [ "$failed" -eq 0 ]; then
    tail -20 "$logf" >&2
    failed=1
  fi
  sed -n '/^\[==========\] .* ran\./,$p' "$logf" >&2
  [ "$failed" -eq 0 ] || status=1
  summary+=("platform_check: $what: $passed tests passed, $failed failed, run $((SECONDS - t0)) s")
}

# run_rostest FILE: one rostest of the package in the amd64 root, counted from its summary
run_rostest() {
  local r=$1 t0=$SECONDS logf="$DIR/rostest-${1%.test}-amd64.log" tests errors failures result
  log "bullseye amd64 rostest $r (log: $logf)"
  set +e
  in_root "$AMD" bash -c "source /ws/devel/setup.bash && ROS_HOME=/ws/ros_home ROS_HOSTNAME=localhost \
    rostest uw_multislam $r" > "$logf" 2>&1
  set -e
  # rostest colours its summary even into a file.
  sed -i 's/\x1b\[[0-9;]*m//g' "$logf"
  tests=$(sed -n 's/^ \* TESTS: //p' "$logf" | tail -1)
  errors=$(sed -n 's/^ \* ERRORS: //p' "$logf" | tail -1)
  failures=$(sed -n 's/^ \* FAILURES: //p' "$logf" | tail -1)
  result=$(sed -n 's/^ \* RESULT: //p' "$logf" | tail -1)
  sed -n '/^SUMMARY/,$p' "$logf" >&2
  if [ "$result" != SUCCESS ]; then
    status=1
    tail -20 "$logf" >&2
  fi
  local counts="${tests:-0} tests, ${errors:-?} errors, ${failures:-?} failures"
  summary+=("platform_check: bullseye amd64 rostest $r: ${result:-no result}, $counts, run $((SECONDS - t0)) s")
}

# --- the amd64 root: always (the native build; for arm64, bullseye's cross compiler) --------------
ROS_PACKAGES=(catkin ros-core-dev libroscpp-dev libnodeletlib-dev libtf2-ros-dev libtf2-geometry-msgs-dev
  libimage-transport-dev libcv-bridge-dev libimage-geometry-dev libcamera-calibration-parsers-dev libroslib-dev
  librosbag-dev ros-message-generation ros-message-runtime ros-std-msgs ros-sensor-msgs ros-nav-msgs
  ros-geometry-msgs ros-visualization-msgs ros-diagnostic-msgs libdiagnostic-updater-dev python3-catkin-pkg
  python3-rospkg python3-roslaunch python3-rostest librostest-dev python3-rosbag)
# What the nodes, launch files and rostests use at run time (scripts/install_deps.sh's), where bullseye has it.
ROS_RUN_PACKAGES=(libnodeletlib-tools rosbash python3-rostopic python3-rosservice python3-nodelet python3-rosnode
  python3-tf2-ros python3-tf2-msgs python3-geometry-msgs python3-sensor-msgs python3-nav-msgs python3-visualization-msgs
  python3-diagnostic-msgs python3-numpy python3-yaml python3-pytest topic-tools libimage-proc-dev)
CORE_PACKAGES=(build-essential cmake libopencv-dev libeigen3-dev libceres-dev libsqlite3-dev libyaml-cpp-dev
  libboost-dev libgtest-dev libgdal-dev python3)
t_setup=$SECONDS
make_root amd64 $SUITE "$AMD" "$MIRROR" "$DIR/debootstrap-amd64.log"
root_sources "$AMD" "$DIR/sources.list"
setup_s=$((SECONDS - t_setup))
bind_ro "$UWMS_REPO" "$AMD$UWMS_REPO"

if [ "$ARCH" = amd64 ]; then
  t0=$SECONDS
  amd_packages=("${CORE_PACKAGES[@]}" g++-9)
  # GeographicLib: libgeographic-dev in Debian 11 and Ubuntu 20.04, libgeographiclib-dev from Debian 12 on.
  if [ -z "$(unavailable "$AMD" libgeographiclib-dev)" ]; then amd_packages+=(libgeographiclib-dev); else
    amd_packages+=(libgeographic-dev); fi
  [ -z "$(unavailable "$AMD" libvlfeat-dev)" ] && amd_packages+=(libvlfeat-dev)
  mapfile -t ros_missing < <(unavailable "$AMD" "${ROS_PACKAGES[@]}")
  if [ ${#ros_missing[@]} -eq 0 ]; then
    mode=full
    mapfile -t run_missing < <(unavailable "$AMD" "${ROS_RUN_PACKAGES[@]}")
    for p in "${ROS_RUN_PACKAGES[@]}"; do [[ " ${run_missing[*]} " == *" $p "* ]] || amd_packages+=("$p"); done
    [ ${#run_missing[@]} -eq 0 ] || log "bullseye lacks ${run_missing[*]}: rostests that need them fail"
    amd_packages+=("${ROS_PACKAGES[@]}")
  else
    mode=core
    log "bullseye lacks ${ros_missing[*]}: the ROS-free core, the simulator and test_core only"
  fi
  root_install "$AMD" "$AMD/.uwms_packages_amd64" "$DIR/apt-amd64.log" "${amd_packages[@]}"
  # Debian 11's libvlfeat-dev (0.9.21+dfsg0, like Ubuntu 20.04's) leaves SIFT out (vl/sift.h, for the
  # patent, expired in 2020); Debian 12's (0.9.21+full) has it and installs on bullseye (glibc 2.29,
  # libgomp1): this host's two packages, fetched by its apt, stand in for a VLFeat built from source.
  if [ ! -e "$AMD/usr/include/vl/sift.h" ]; then
    mkdir -p "$DIR/debs"
    (cd "$DIR/debs" && apt-get download libvlfeat1 libvlfeat-dev > "$DIR/apt-download.log" 2>&1) \
      || { tail "$DIR/apt-download.log" >&2; die "apt-get download libvlfeat1 libvlfeat-dev failed"; }
    cp "$DIR"/debs/libvlfeat*.deb "$AMD/tmp/"
    in_root "$AMD" bash -c "dpkg -i /tmp/libvlfeat*.deb && rm /tmp/libvlfeat*.deb" > "$DIR/dpkg-vlfeat.log" 2>&1 \
      || { tail "$DIR/dpkg-vlfeat.log" >&2; die "dpkg -i of Debian 12's VLFeat in the bullseye root failed"; }
    log "bullseye's libvlfeat-dev has no SIFT: Debian 12's $(ls "$DIR"/debs/libvlfeat-dev_*.deb | xargs -n1 basename) installed instead"
  fi
  setup_s=$((setup_s + SECONDS - t0))
  versions=$(in_root "$AMD" dpkg-query -W -f='${Package} ${Version}\n' g++-10 g++-9 libopencv-dev libgdal-dev \
    libceres-dev cmake libboost-dev libeigen3-dev libvlfeat-dev libgeographic-dev ros-core-dev 2>/dev/null \
    | tr '\n' ';' || true)
  log "bullseye amd64: $versions"
  [ "${UWMS_ROOT_SETUP_ONLY:-0}" = 0 ] || { echo "platform_check: Debian $SUITE amd64 roots set up ($DIR), root setup $setup_s s; nothing built (UWMS_ROOT_SETUP_ONLY)"; exit 0; }

  # 1. The package (or the core) with bullseye's GCC 10, every SIFT it has.
  t0=$SECONDS
  set +e
  if [ "${UWMS_PLATFORM_PACKAGE:-1}" = 0 ]; then
    rc=skipped
  elif [ $mode = full ]; then
    # A fresh CMake cache each run (the objects stay): Debian 11's cmake-extras GMockConfig defines the
    # gmock_main target only when it is first found; a re-configure from the cache links a missing one.
    # --force-cmake: with a Makefile there, catkin_make would let make re-run CMake without its own
    # arguments, and the devel space would move to build/devel (the tests then run from the old one).
    in_root "$AMD" bash -c "mkdir -p /ws/src && ln -sfn '$UWMS_REPO' /ws/src/uw_multislam && cd /ws && \
      rm -f build/CMakeCache.txt && \
      catkin_make --force-cmake -DPYTHON_EXECUTABLE=/usr/bin/python3 -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCATKIN_ENABLE_TESTING=ON \
        -DUWMS_WERROR=ON -j$JOBS && \
      make -C build -j$JOBS tests" > "$DIR/build-amd64.log" 2>&1
    rc=$?
  else
    in_root "$AMD" bash -c "cmake -S '$UWMS_REPO/scripts/arm64' -B /build/core -DUWMS_WERROR=ON && \
      cmake --build /build/core -j$JOBS" > "$DIR/build-amd64.log" 2>&1
    rc=$?
  fi
  set -e
  build_s=$((SECONDS - t0))
  [ $rc = skipped ] || grep -E 'uw_multislam SIFT|GDAL not found|warning:|error:' "$DIR/build-amd64.log" >&2 || true
  if [ $rc = skipped ]; then
    summary+=("platform_check: bullseye amd64 $mode build: skipped (UWMS_PLATFORM_PACKAGE=0)")
  elif [ $rc -ne 0 ]; then
    tail -30 "$DIR/build-amd64.log" >&2
    summary+=("platform_check: bullseye amd64 $mode build FAILED after $build_s s ($DIR/build-amd64.log)")
    status=1
  else
    summary+=("platform_check: bullseye amd64 $mode build (GCC 10, -Werror): ok, $build_s s, $(grep -c 'warning:' "$DIR/build-amd64.log" || true) warnings")
    if [ $mode = full ]; then
      bin=/ws/devel/lib/uw_multislam
      for t in test_core test_conversions test_no_gdal test_work_queue test_dataset_bag; do
        run_gtest "bullseye amd64 $t" "$AMD/ws/$t.xml" "$DIR/$t-amd64.log" \
          in_root "$AMD" bash -c "cd /ws && $bin/$t --gtest_output=xml:/ws/$t.xml $*"
      done
      # rostests in the root (each starts its own master on a free port); /dev/shm, as on a real system.
      mountpoint -q "$AMD/dev/shm" || { mkdir -p "$AMD/dev/shm" && mount -t tmpfs -o mode=1777 shm "$AMD/dev/shm"; }
      for r in $ROSTESTS; do
        run_rostest "$r"
      done
    else
      run_gtest "bullseye amd64 test_core" "$AMD/build/core/test_core.xml" "$DIR/test_core-amd64.log" \
        in_root "$AMD" bash -c "cd /build/core && ./test_core --gtest_output=xml:/build/core/test_core.xml $*"
    fi
  fi

  # 2. Ubuntu 20.04's compiler and its OpenCV without SIFT: g++-9, VLFeat's SIFT alone.
  if [ ! -e "$AMD/usr/include/vl/sift.h" ]; then
    summary+=("platform_check: bullseye amd64 g++-9 core: not built (no VLFeat with SIFT)")
  else
    t0=$SECONDS
    set +e
    in_root "$AMD" bash -c "cmake -S '$UWMS_REPO/scripts/arm64' -B /build/gcc9 -DCMAKE_CXX_COMPILER=g++-9 \
      -DUWMS_FORCE_SIFT_BACKEND=vlfeat -DUWMS_WERROR=ON && cmake --build /build/gcc9 -j$JOBS" \
      > "$DIR/build-amd64-gcc9.log" 2>&1
    rc=$?
    set -e
    build_s=$((SECONDS - t0))
    grep -E 'uw_multislam SIFT|warning:|error:' "$DIR/build-amd64-gcc9.log" >&2 || true
    if [ $rc -ne 0 ]; then
      tail -30 "$DIR/build-amd64-gcc9.log" >&2
      summary+=("platform_check: bullseye amd64 g++-9 core (VLFeat SIFT only) build FAILED after $build_s s")
      status=1
    else
      summary+=("platform_check: bullseye amd64 g++-9 core (VLFeat SIFT only, -Werror) build: ok, $build_s s")
      run_gtest "bullseye amd64 g++-9 test_core (VLFeat SIFT only)" "$AMD/build/gcc9/test_core.xml" \
        "$DIR/test_core-amd64-gcc9.log" \
        in_root "$AMD" bash -c "cd /build/gcc9 && ./test_core --gtest_output=xml:/build/gcc9/test_core.xml $*"
    fi
  fi
else
  # --- arm64: the arm64 root as sysroot of bullseye's cross compiler in the amd64 root ----------------
  t0=$SECONDS
  root_install "$AMD" "$AMD/.uwms_packages_amd64-cross" "$DIR/apt-amd64-cross.log" cmake make g++-aarch64-linux-gnu python3
  make_root arm64 $SUITE "$ARM" "$MIRROR" "$DIR/debootstrap-arm64.log"
  root_sources "$ARM" "$DIR/sources.list"
  # GeographicLib for the export library (test_core links it); no GDAL (optional: GeoTIFFs refused).
  arm_packages=(libc6-dev libopencv-dev libeigen3-dev libceres-dev libsqlite3-dev libyaml-cpp-dev libboost-dev libgtest-dev
    libgeographic-dev)
  [ -z "$(unavailable "$ARM" libvlfeat-dev)" ] && arm_packages+=(libvlfeat-dev)
  if ! cmp -s <(printf '%s\n' "${arm_packages[@]}") "$ARM/.uwms_packages_arm64"; then
    unmount_below "$DIR"
    root_install "$ARM" "$ARM/.uwms_packages_arm64" "$DIR/apt-arm64.log" "${arm_packages[@]}"
    # The arm64 root is the amd64 root's /sysroot: its absolute symlinks would resolve in the amd64 root.
    relative_symlinks "$ARM"
    bind_ro "$UWMS_REPO" "$AMD$UWMS_REPO"
  fi
  setup_s=$((setup_s + SECONDS - t0))
  bind_ro "$ARM" "$AMD/sysroot"
  versions=$(in_root "$ARM" dpkg-query -W -f='${Package} ${Version}\n' libopencv-dev libceres-dev libeigen3-dev \
    libvlfeat-dev 2>/dev/null | tr '\n' ';' || true)
  log "bullseye arm64: $versions; cross: $(in_root "$AMD" aarch64-linux-gnu-g++ --version | head -1)"
  [ "${UWMS_ROOT_SETUP_ONLY:-0}" = 0 ] || { echo "platform_check: Debian $SUITE arm64 roots set up ($DIR), root setup $setup_s s; nothing built (UWMS_ROOT_SETUP_ONLY)"; exit 0; }
  aarch64_toolchain "$AMD/build/aarch64-toolchain.cmake" /sysroot
  t0=$SECONDS
  set +e
  in_root "$AMD" bash -c "cmake -S '$UWMS_REPO/scripts/arm64' -B /build/arm64 \
    -DCMAKE_TOOLCHAIN_FILE=/build/aarch64-toolchain.cmake -DUWMS_WERROR=ON && cmake --build /build/arm64 -j$JOBS" \
    > "$DIR/build-arm64.log" 2>&1
  rc=$?
  set -e
  build_s=$((SECONDS - t0))
  grep -E 'uw_multislam SIFT|OpenCV .*Ceres|warning:|error:' "$DIR/build-arm64.log" >&2 || true
  if [ $rc -ne 0 ]; then
    tail -30 "$DIR/build-arm64.log" >&2
    summary+=("platform_check: bullseye arm64 core build FAILED after $build_s s ($DIR/build-arm64.log)")
    status=1
  else
    summary+=("platform_check: bullseye arm64 core build (cross GCC 10, -Werror): ok, $build_s s")
    # An aarch64 ELF (e_machine 0xb7 at offset 18), not a host binary by mistake.
    [ "$(od -An -tx1 -j18 -N2 "$AMD/build/arm64/test_core" | tr -d ' \n')" = b700 ] || die "test_core is not an aarch64 ELF"
    # qemu-aarch64-static -L: the arm64 loader and libraries from the root; the package's own
    # libraries from the build (their RPATH is the amd64 root's /build/arm64); the repository (which
    # test_core reads through UWMS_SOURCE_DIR) is at the same path on the host.
    run_gtest "bullseye arm64 test_core (qemu-user)" "$DIR/test_core-arm64.xml" "$DIR/test_core-arm64.log" \
      bash -c "cd '$AMD/build/arm64' && qemu-aarch64-static -L '$ARM' -E LD_LIBRARY_PATH='$AMD/build/arm64' \
        ./test_core --gtest_output=xml:'$DIR/test_core-arm64.xml' $*"
  fi
fi

echo "platform_check: Debian $SUITE $ARCH, $(date -u '+%F %H:%M UTC'), root setup $setup_s s, total $((SECONDS - t_start)) s"
printf '%s\n' "${summary[@]}"
exit $status
