#!/usr/bin/env bash
# arm64 check: builds the ROS-free core (uw_multislam_core), the simulator and the export library
# (uw_multislam_sim, uw_multislam_export, which the tests link) and the core's gtests (test_core) for aarch64, the CPU of
# a Jetson-class vehicle computer, and runs the tests under emulation (qemu-user). Not part of CI
# (about 47 min from nothing, 20 to 25 min again, doc/arm64_check.md).
#
# How: a Debian 12 arm64 root file system (scripts/debian_root.sh, as scripts/platform_check.sh's
# bullseye roots: debootstrap --variant=minbase, its second stage under qemu through binfmt_misc) holds the arm64 -dev libraries (OpenCV, Eigen, Ceres, SQLite, yaml-cpp,
# Boost, gtest), installed by apt-get inside it; nothing arm64 goes into the host's own dpkg. The host's
# cross compiler (aarch64-linux-gnu-g++, the same GCC 12 as Debian's arm64 g++) builds with that
# root as --sysroot (scripts/arm64/CMakeLists.txt: plain CMake, source lists read from the
# package's CMakeLists.txt), and qemu-aarch64-static -L <root> runs test_core. Cross-compiling,
# not compiling inside the root under emulation: Debian's arm64 g++ under qemu took 6 to 7 times as
# long on the same files for the same assembly (doc/arm64_check.md); only the test run needs the
# arm64 CPU.
#
# usage: sudo scripts/arm64_check.sh [gtest arguments, e.g. --gtest_filter=Iekf.*]
#   UWMS_ARM64_ROOT   folder of the root file system and the build (default <repo>_arm64 beside the
#                     repository, as the catkin workspace <repo>_ws; rootfs/ and build/ in it)
#   UWMS_ARM64_JOBS   compile jobs (default 1: the machine is shared)
#   UWMS_ARM64_MIRROR Debian mirror (default: the one the host's apt uses)
#   UWMS_ROOT_SETUP_ONLY 1: set the root up (debootstrap, apt-get; scripts/debian_root.sh) and stop
# Idempotent and incremental: a second run reuses the root file system and the build.
# Prints the gtest summary and, last, "arm64_check: N tests passed, M failed (aarch64, qemu-user),
# build X s, run Y s"; exits non-zero when the build or any test fails.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
source "$(dirname "${BASH_SOURCE[0]}")/debian_root.sh"
ARM64_DIR=${UWMS_ARM64_ROOT:-$(dirname "$UWMS_REPO")/$(basename "$UWMS_REPO")_arm64}
ROOTFS=$ARM64_DIR/rootfs
BUILD=$ARM64_DIR/build
JOBS=${UWMS_ARM64_JOBS:-1}
SUITE=bookworm
log() { echo "[arm64_check] $*" >&2; }
die() { log "$*"; exit 1; }
[ "$(id -u)" -eq 0 ] || die "needs root (debootstrap, chroot, binfmt_misc): run it with sudo"
case "$ARM64_DIR" in "$UWMS_REPO"|"$UWMS_REPO"/*) die "UWMS_ARM64_ROOT=$ARM64_DIR is inside the repository";; esac
mkdir -p "$ARM64_DIR"

# --- host tools (amd64 packages only: cross compiler, qemu, debootstrap); arm64 binaries (the root's
# dpkg, apt, maintainer scripts) run through qemu by binfmt_misc ---------------------------------
host_install "$ARM64_DIR/host_apt.log" qemu-user-static binfmt-support debootstrap g++-aarch64-linux-gnu cmake make python3
binfmt_arm64 > /dev/null

# --- the arm64 root file system (scripts/debian_root.sh), from the mirror the host's apt uses -----
MIRROR=${UWMS_ARM64_MIRROR:-$(host_uri $SUITE)}
trap 'unmount_below "$ROOTFS"' EXIT
t_setup=$SECONDS
make_root arm64 $SUITE "$ROOTFS" "$MIRROR" "$ARM64_DIR/debootstrap.log"

# The arm64 libraries the core, the simulator, the export library and test_core need (find_package in
# scripts/arm64/CMakeLists.txt; Boost's headers for boost/math in the back-end; GeographicLib for the
# export library, GDAL left out: optional, GeoTIFFs refused), and libc6-dev for the sysroot's crt
# files and libc.
ROOT_PACKAGES=(libc6-dev libopencv-dev libeigen3-dev libceres-dev libsqlite3-dev libyaml-cpp-dev libboost-dev libgtest-dev
  libgeographiclib-dev)
{
  echo "deb $MIRROR $SUITE main"
  echo "deb $MIRROR $SUITE-updates main"
  # Security updates only where the host's apt lists them (its archive may not serve them).
  if grep -rqsE "^[^#]*[[:space:]]$SUITE-security([[:space:]]|\$)" /etc/apt/sources.list /etc/apt/sources.list.d/; then
    echo "deb $(host_uri $SUITE-security) $SUITE-security main"
  fi
} > "$ARM64_DIR/sources.list"
# The package list and the sources together: either changed, apt-get install again.
stamp_list=("${ROOT_PACKAGES[@]}" "sources: $(tr '\n' ';' < "$ARM64_DIR/sources.list")")
if ! cmp -s <(printf '%s\n' "${stamp_list[@]}") "$ROOTFS/.uwms_packages"; then
  root_sources "$ROOTFS" "$ARM64_DIR/sources.list"
  rm -f "$ROOTFS/.uwms_packages.apt"
  root_install "$ROOTFS" "$ROOTFS/.uwms_packages.apt" "$ARM64_DIR/root_apt.log" "${ROOT_PACKAGES[@]}"
  relative_symlinks "$ROOTFS"
  printf '%s\n' "${stamp_list[@]}" > "$ROOTFS/.uwms_packages"
fi
unmount_below "$ROOTFS"
setup_s=$((SECONDS - t_setup))
log "root setup: $setup_s s"
[ "${UWMS_ROOT_SETUP_ONLY:-0}" = 0 ] || { echo "arm64_check: root set up ($ROOTFS), build and tests not run (UWMS_ROOT_SETUP_ONLY)"; exit 0; }

# --- cross build (host compiler, the root as sysroot) --------------------------------------------
toolchain=$ARM64_DIR/aarch64-toolchain.cmake
aarch64_toolchain "$toolchain" "$ROOTFS" qemu-aarch64-static -L "\"$ROOTFS\""

t0=$SECONDS
log "configure and build (cross, -j$JOBS) in $BUILD (log: $ARM64_DIR/build.log)"
set +e
{ cmake -S "$UWMS_REPO/scripts/arm64" -B "$BUILD" -DCMAKE_TOOLCHAIN_FILE="$toolchain" \
    && cmake --build "$BUILD" -j "$JOBS"; } > "$ARM64_DIR/build.log" 2>&1
build_rc=$?
set -e
build_s=$((SECONDS - t0))
grep -E 'sources from|OpenCV .*Ceres|warning:|error:|Built target' "$ARM64_DIR/build.log" >&2 || true
if [ $build_rc -ne 0 ]; then
  tail -30 "$ARM64_DIR/build.log" >&2
  echo "arm64_check: build failed (aarch64, cross), build $build_s s ($ARM64_DIR/build.log)"
  exit 1
fi
warnings=$(grep -c 'warning:' "$ARM64_DIR/build.log" || true)
log "build: $build_s s, $warnings compiler warnings in this run's output"
# An aarch64 ELF (e_machine 0xb7 at offset 18), not a host binary by mistake.
[ "$(od -An -tx1 -j18 -N2 "$BUILD/test_core" | tr -d ' \n')" = b700 ] || die "$BUILD/test_core is not an aarch64 ELF"

# --- test run under qemu-user --------------------------------------------------------------------
# qemu-aarch64-static -L: the arm64 loader and libraries come from the root; paths not in the root
# (the repository, which test_core reads through UWMS_SOURCE_DIR) are the host's.
t0=$SECONDS
xml=$ARM64_DIR/test_core.xml
rm -f "$xml"
log "test_core under qemu-aarch64-static (log: $ARM64_DIR/test_core.log)"
set +e
(cd "$BUILD" && qemu-aarch64-static -L "$ROOTFS" ./test_core --gtest_output="xml:$xml" "$@") > "$ARM64_DIR/test_core.log" 2>&1
rc=$?
set -e
run_s=$((SECONDS - t0))
# The summary: gtest's last lines (from "[==========] N tests ... ran."), the failures listed there.
sed -n '/^\[==========\] .* ran\./,$p' "$ARM64_DIR/test_core.log"
read -r passed failed < <(gtest_counts "$xml" "$ARM64_DIR/test_core.log")
if [ "$rc" -ne 0 ] && [ "$failed" -eq 0 ]; then
  tail -20 "$ARM64_DIR/test_core.log"
  log "test_core exited with $rc and no failed test in its XML (a crash?)"
  failed=$((failed + 1))
fi
echo "arm64_check: $passed tests passed, $failed failed (aarch64, qemu-user), build $build_s s, run $run_s s" \
  "(root setup $setup_s s)"
[ "$rc" -eq 0 ] && [ "$failed" -eq 0 ]
