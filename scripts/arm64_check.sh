#!/usr/bin/env bash
# arm64 check: builds the ROS-free core (uw_multislam_core), the simulator and the export library
# (uw_multislam_sim, uw_multislam_export, which the tests link) and the core's gtests (test_core) for aarch64, the CPU of
# a Jetson-class vehicle computer, and runs the tests under emulation (qemu-user). Not part of CI
# (about 47 min from nothing, 20 to 25 min again, README "arm64 check").
#
# How: a Debian 12 arm64 root file system (debootstrap --variant=minbase, its second stage under
# qemu through binfmt_misc) holds the arm64 -dev libraries (OpenCV, Eigen, Ceres, SQLite, yaml-cpp,
# Boost, gtest), installed by apt-get inside it; nothing arm64 goes into the host's own dpkg. The host's
# cross compiler (aarch64-linux-gnu-g++, the same GCC 12 as Debian's arm64 g++) builds with that
# root as --sysroot (scripts/arm64/CMakeLists.txt: plain CMake, source lists read from the
# package's CMakeLists.txt), and qemu-aarch64-static -L <root> runs test_core. Cross-compiling,
# not compiling inside the root under emulation: Debian's arm64 g++ under qemu took 6 to 7 times as
# long on the same files for the same assembly (README "arm64 check"); only the test run needs the
# arm64 CPU.
#
# usage: sudo scripts/arm64_check.sh [gtest arguments, e.g. --gtest_filter=Iekf.*]
#   UWMS_ARM64_ROOT   folder of the root file system and the build (default <repo>_arm64 beside the
#                     repository, as the catkin workspace <repo>_ws; rootfs/ and build/ in it)
#   UWMS_ARM64_JOBS   compile jobs (default 1: the machine is shared)
#   UWMS_ARM64_MIRROR Debian mirror (default: the one the host's apt uses)
# Idempotent and incremental: a second run reuses the root file system and the build.
# Prints the gtest summary and, last, "arm64_check: N tests passed, M failed (aarch64, qemu-user),
# build X s, run Y s"; exits non-zero when the build or any test fails.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
ARM64_DIR=${UWMS_ARM64_ROOT:-$(dirname "$UWMS_REPO")/$(basename "$UWMS_REPO")_arm64}
ROOTFS=$ARM64_DIR/rootfs
BUILD=$ARM64_DIR/build
JOBS=${UWMS_ARM64_JOBS:-1}
SUITE=bookworm
APT=(apt-get -o DPkg::Lock::Timeout=900 -y -qq --no-install-recommends)
export DEBIAN_FRONTEND=noninteractive
log() { echo "[arm64_check] $*" >&2; }
die() { log "$*"; exit 1; }
[ "$(id -u)" -eq 0 ] || die "needs root (debootstrap, chroot, binfmt_misc): run it with sudo"
case "$ARM64_DIR" in "$UWMS_REPO"|"$UWMS_REPO"/*) die "UWMS_ARM64_ROOT=$ARM64_DIR is inside the repository";; esac
mkdir -p "$ARM64_DIR"

# --- host tools (amd64 packages only: cross compiler, qemu, debootstrap) -------------------------
HOST_PACKAGES=(qemu-user-static binfmt-support debootstrap g++-aarch64-linux-gnu cmake make python3)
missing=()
for p in "${HOST_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  log "installing on the host: ${missing[*]}"
  "${APT[@]}" install "${missing[@]}" > "$ARM64_DIR/host_apt.log" 2>&1 || {
    apt-get -o DPkg::Lock::Timeout=900 -qq update
    "${APT[@]}" install "${missing[@]}" > "$ARM64_DIR/host_apt.log" 2>&1
  } || { tail -20 "$ARM64_DIR/host_apt.log" >&2; die "host apt-get install failed ($ARM64_DIR/host_apt.log)"; }
fi

# --- binfmt_misc: arm64 binaries (the chroot's dpkg, apt, maintainer scripts) run through qemu -----
binfmt=/proc/sys/fs/binfmt_misc
[ -e $binfmt/register ] || mount -t binfmt_misc binfmt_misc $binfmt \
  || die "cannot mount binfmt_misc on $binfmt (a container without it cannot run the chroot)"
[ -e $binfmt/qemu-aarch64 ] || update-binfmts --enable qemu-aarch64 || die "update-binfmts --enable qemu-aarch64 failed"
grep -q '^enabled' $binfmt/qemu-aarch64 || die "$binfmt/qemu-aarch64 is disabled"
# Debian registers it with the F flag (the interpreter opened at registration, so it works in a
# chroot); without it the interpreter must be inside the root too.
fix_binary=yes
grep -q '^flags:.*F' $binfmt/qemu-aarch64 || fix_binary=no

# --- the arm64 root file system -----------------------------------------------------------------
# The mirror the host's apt uses (only Debian's archive is reachable here): one-line sources first,
# then deb822 .sources stanzas whose Suites name the suite.
host_uri() {  # $1: suite
  local uri
  uri=$(cat /etc/apt/sources.list /etc/apt/sources.list.d/*.list 2>/dev/null | awk -v s="$1" '
    $1 == "deb" { i = 2; if ($2 ~ /^\[/) { while (i < NF && $i !~ /\]$/) i++; i++ }
                  if ($(i + 1) == s) { print $i; exit } }')
  if [ -z "$uri" ]; then
    uri=$(cat /etc/apt/sources.list.d/*.sources 2>/dev/null | awk -v s="$1" '
      function flush() { if (deb && has && u != "" && !done) { print u; done = 1 } deb = has = 0; u = "" }
      /^[ \t]*$/ { flush(); next }
      /^Types:/ { for (i = 2; i <= NF; i++) if ($i == "deb") deb = 1 }
      /^URIs:/ { u = $2 }
      /^Suites:/ { for (i = 2; i <= NF; i++) if ($i == s) has = 1 }
      END { flush() }')
  fi
  echo "$uri"
}
MIRROR=${UWMS_ARM64_MIRROR:-$(host_uri $SUITE)}
MIRROR=${MIRROR:-http://deb.debian.org/debian}
SECURITY=$(host_uri $SUITE-security)

# Everything mounted below the root (its /proc while apt runs) comes down on exit, error or ^C.
unmount_all() {
  local m
  for m in $(awk -v r="$ROOTFS/" 'index($5, r) == 1 { print $5 }' /proc/self/mountinfo | sort -r); do
    umount "$m" 2>/dev/null || umount -l "$m" || true
  done
}
trap unmount_all EXIT
in_root() {  # runs a command in the root, with its own /proc
  mountpoint -q "$ROOTFS/proc" || mount -t proc proc "$ROOTFS/proc"
  chroot "$ROOTFS" /usr/bin/env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin DEBIAN_FRONTEND=noninteractive LC_ALL=C "$@"
}

t_setup=$SECONDS
if [ ! -e "$ROOTFS/.uwms_debootstrap_done" ]; then
  unmount_all
  [ -e "$ROOTFS" ] && { log "removing the unfinished root $ROOTFS"; rm -rf --one-file-system "$ROOTFS"; }
  log "debootstrap $SUITE arm64 (minbase) from $MIRROR into $ROOTFS (first stage)"
  debootstrap --arch=arm64 --variant=minbase --foreign $SUITE "$ROOTFS" "$MIRROR" > "$ARM64_DIR/debootstrap.log" 2>&1 \
    || { tail -20 "$ARM64_DIR/debootstrap.log" >&2; die "debootstrap failed ($ARM64_DIR/debootstrap.log)"; }
  if [ $fix_binary = no ]; then
    install -D /usr/bin/qemu-aarch64-static "$ROOTFS/usr/bin/qemu-aarch64-static"
    interp=$(awk '/^interpreter/ { print $2 }' $binfmt/qemu-aarch64)
    install -D "$interp" "$ROOTFS$interp"
  fi
  log "debootstrap second stage (arm64 dpkg under qemu)"
  chroot "$ROOTFS" /debootstrap/debootstrap --second-stage >> "$ARM64_DIR/debootstrap.log" 2>&1 \
    || { tail -20 "$ARM64_DIR/debootstrap.log" >&2; die "debootstrap --second-stage failed ($ARM64_DIR/debootstrap.log)"; }
  touch "$ROOTFS/.uwms_debootstrap_done"
  log "root file system: $((SECONDS - t_setup)) s"
fi

# The arm64 libraries the core, the simulator, the export library and test_core need (find_package in
# scripts/arm64/CMakeLists.txt; Boost's headers for boost/math in the back-end; GeographicLib for the
# export library, GDAL left out: optional, GeoTIFFs refused), and libc6-dev for the sysroot's crt
# files and libc.
ROOT_PACKAGES=(libc6-dev libopencv-dev libeigen3-dev libceres-dev libsqlite3-dev libyaml-cpp-dev libboost-dev libgtest-dev
  libgeographiclib-dev)
{
  echo "deb $MIRROR $SUITE main"
  echo "deb $MIRROR $SUITE-updates main"
  [ -z "$SECURITY" ] || echo "deb $SECURITY $SUITE-security main"
} > "$ARM64_DIR/sources.list"
stamp="$ROOTFS/.uwms_packages"
if ! cmp -s <(printf '%s\n' "${ROOT_PACKAGES[@]}"; cat "$ARM64_DIR/sources.list") "$stamp"; then
  t0=$SECONDS
  cp "$ARM64_DIR/sources.list" "$ROOTFS/etc/apt/sources.list"
  cp /etc/resolv.conf "$ROOTFS/etc/resolv.conf"
  log "apt-get install in the arm64 root: ${ROOT_PACKAGES[*]}"
  { in_root apt-get -qq update && in_root "${APT[@]}" install "${ROOT_PACKAGES[@]}" && in_root apt-get clean; } \
    > "$ARM64_DIR/root_apt.log" 2>&1 \
    || { tail -20 "$ARM64_DIR/root_apt.log" >&2; die "apt-get in the arm64 root failed ($ARM64_DIR/root_apt.log)"; }
  unmount_all
  # Absolute symlinks (update-alternatives' libblas.so.3 -> /etc/alternatives/... -> ...) would point
  # into the host when the root is a sysroot (the linker) or a qemu -L prefix (the loader): made
  # relative, they resolve the same in the chroot and from outside it.
  n=0
  while IFS= read -r -d '' l; do
    t=$(readlink "$l")
    ln -sfn "$(realpath -s -m --relative-to="$(dirname "$l")" "$ROOTFS$t")" "$l"
    n=$((n + 1))
  done < <(find "$ROOTFS" -xdev -type l -lname '/*' ! -path "$ROOTFS/proc/*" ! -path "$ROOTFS/dev/*" -print0)
  log "$n absolute symlinks in the root made relative"
  { printf '%s\n' "${ROOT_PACKAGES[@]}"; cat "$ARM64_DIR/sources.list"; } > "$stamp"
  log "arm64 packages: $((SECONDS - t0)) s"
fi
setup_s=$((SECONDS - t_setup))

# --- cross build (host compiler, the root as sysroot) --------------------------------------------
toolchain=$ARM64_DIR/aarch64-toolchain.cmake
cat > "$toolchain.new" <<EOF
# Written by scripts/arm64_check.sh: the host's cross compiler, $ROOTFS as sysroot.
set(CMAKE_SYSTEM_NAME Linux)
set(CMAKE_SYSTEM_PROCESSOR aarch64)
set(CMAKE_C_COMPILER aarch64-linux-gnu-gcc)
set(CMAKE_CXX_COMPILER aarch64-linux-gnu-g++)
set(CMAKE_LIBRARY_ARCHITECTURE aarch64-linux-gnu)
set(CMAKE_SYSROOT "$ROOTFS")
set(CMAKE_FIND_ROOT_PATH "$ROOTFS")
set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_PACKAGE ONLY)
set(CMAKE_CROSSCOMPILING_EMULATOR qemu-aarch64-static -L "$ROOTFS")
EOF
cmp -s "$toolchain.new" "$toolchain" && rm "$toolchain.new" || mv "$toolchain.new" "$toolchain"

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
# Counted from gtest's XML: skipped and disabled tests count neither way.
count_py='
import sys, xml.etree.ElementTree as ET
passed = failed = 0
try:
    for c in ET.parse(sys.argv[1]).getroot().iter("testcase"):
        if c.get("result", "completed") != "completed" or c.get("status") == "notrun":
            continue
        if c.find("failure") is not None:
            failed += 1
        else:
            passed += 1
except Exception:
    pass
print(passed, failed)'
if [ -s "$xml" ]; then
  read -r passed failed < <(python3 -c "$count_py" "$xml")
else  # no XML: test_core died before its end; count the tests that finished from its log
  passed=$(grep -c '^\[       OK \]' "$ARM64_DIR/test_core.log" || true)
  failed=$(grep -c '^\[  FAILED  \] .* ms)$' "$ARM64_DIR/test_core.log" || true)
fi
if [ "$rc" -ne 0 ] && [ "$failed" -eq 0 ]; then
  tail -20 "$ARM64_DIR/test_core.log"
  log "test_core exited with $rc and no failed test in its XML (a crash?)"
  failed=$((failed + 1))
fi
echo "arm64_check: $passed tests passed, $failed failed (aarch64, qemu-user), build $build_s s, run $run_s s" \
  "(root setup $setup_s s)"
[ "$rc" -eq 0 ] && [ "$failed" -eq 0 ]
