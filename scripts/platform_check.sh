#!/usr/bin/env bash
# Platform check: builds uw_multislam against Debian 11 (bullseye), the nearest this machine can reach
# to the platforms users run (Ubuntu 20.04 with ROS Noetic; JetPack 5, Ubuntu 20.04 arm64): GCC 10
# (and GCC 9, Ubuntu 20.04's), OpenCV 4.5.1, GDAL 3.2 (no CMake config file: FindGDAL), Ceres 2.0,
# CMake 3.18, Boost 1.74, Eigen 3.3, VLFeat 0.9.21 (amd64 only) and Debian's ROS 1 packages. Runs the
# gtests there and prints their counts. Not part of CI (an hour or more per architecture).
#
#   amd64: a bullseye amd64 root (debootstrap --variant=minbase); in it, with its own compilers:
#     1. the whole package with catkin_make when every ROS -dev package it needs is in bullseye
#        (else the ROS-free core, the simulator and test_core with plain CMake, scripts/arm64/
#        CMakeLists.txt, and the missing packages named); then test_core, test_no_gdal and, for the
#        whole package, test_conversions;
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
#   UWMS_PLATFORM_PACKAGE amd64 only: 0 skips step 1 (the package with GCC 10, an hour or more at -j1 from
#                         nothing) and runs step 2 alone (default 1)
# Idempotent and incremental: a second run reuses the roots and the builds. The repository is
# bind-mounted read-only into the amd64 root at its own path. Prints, last, one line per build:
# "platform_check: <what>: N tests passed, M failed (...), build X s, run Y s"; exits non-zero when
# a build or a test fails.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
ARCH=${1:-}
case "$ARCH" in amd64 | arm64) shift ;; *) echo "usage: sudo $0 amd64|arm64 [gtest arguments]" >&2; exit 2 ;; esac
DIR=${UWMS_PLATFORM_ROOT:-$(dirname "$UWMS_REPO")/$(basename "$UWMS_REPO")_platform}
SUITE=bullseye
AMD=$DIR/$SUITE-amd64
ARM=$DIR/$SUITE-arm64
JOBS=${UWMS_PLATFORM_JOBS:-1}
APT=(apt-get -o DPkg::Lock::Timeout=900 -y -qq --no-install-recommends)
export DEBIAN_FRONTEND=noninteractive
log() { echo "[platform_check] $*" >&2; }
die() { log "$*"; exit 1; }
[ "$(id -u)" -eq 0 ] || die "needs root (debootstrap, chroot, mount): run it with sudo"
case "$DIR" in "$UWMS_REPO" | "$UWMS_REPO"/*) die "UWMS_PLATFORM_ROOT=$DIR is inside the repository" ;; esac
mkdir -p "$DIR"
t_start=$SECONDS

# --- host tools ------------------------------------------------------------------------------------
HOST_PACKAGES=(debootstrap python3)
[ "$ARCH" = arm64 ] && HOST_PACKAGES+=(qemu-user-static binfmt-support)
missing=()
for p in "${HOST_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  log "installing on the host: ${missing[*]}"
  { "${APT[@]}" install "${missing[@]}" || { apt-get -qq update && "${APT[@]}" install "${missing[@]}"; }; } \
    > "$DIR/host_apt.log" 2>&1 || { tail -20 "$DIR/host_apt.log" >&2; die "host apt-get install failed"; }
fi
if [ "$ARCH" = arm64 ]; then
  binfmt=/proc/sys/fs/binfmt_misc
  [ -e $binfmt/register ] || mount -t binfmt_misc binfmt_misc $binfmt \
    || die "cannot mount binfmt_misc on $binfmt (a container without it cannot run the arm64 root)"
  [ -e $binfmt/qemu-aarch64 ] || update-binfmts --enable qemu-aarch64 || die "update-binfmts --enable qemu-aarch64 failed"
  grep -q '^enabled' $binfmt/qemu-aarch64 || die "$binfmt/qemu-aarch64 is disabled"
fi

# --- mirror: the host's Debian archive (only it is reachable here), its one-line or deb822 sources ----
host_uri() {
  local uri
  uri=$(cat /etc/apt/sources.list /etc/apt/sources.list.d/*.list 2>/dev/null | awk '
    $1 == "deb" { i = 2; if ($2 ~ /^\[/) { while (i < NF && $i !~ /\]$/) i++; i++ }
                  if ($i ~ /debian\/?$/) { print $i; exit } }')
  [ -n "$uri" ] || uri=$(cat /etc/apt/sources.list.d/*.sources 2>/dev/null | awk '
    /^URIs:/ { for (i = 2; i <= NF; i++) if ($i ~ /debian\/?$/) { print $i; exit } }')
  echo "${uri:-http://deb.debian.org/debian}"
}
MIRROR=${UWMS_PLATFORM_MIRROR:-$(host_uri)}

# --- mounts: everything below the roots comes down on exit, error or ^C ---------------------------
unmount_all() {
  local m
  for m in $(awk -v r="$DIR/" 'index($5, r) == 1 { print $5 }' /proc/self/mountinfo | sort -r); do
    umount "$m" 2>/dev/null || umount -l "$m" || true
  done
}
trap unmount_all EXIT
in_root() {  # in_root ROOT COMMAND...: a command in the root, with its own /proc and a read-only /sys
  local root=$1; shift
  mountpoint -q "$root/proc" || mount -t proc proc "$root/proc"
  # As on a real system, /sys is not writable (a store test expects a path there to be refused).
  mountpoint -q "$root/sys" || mount -t sysfs -o ro sysfs "$root/sys"
  chroot "$root" /usr/bin/env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin HOME=/root DEBIAN_FRONTEND=noninteractive \
    LC_ALL=C "$@"
}
bind_ro() {  # bind_ro SOURCE TARGET
  mkdir -p "$2"
  mountpoint -q "$2" || { mount --bind "$1" "$2" && mount -o remount,bind,ro "$2"; }
}

make_root() {  # make_root ARCH ROOT
  local arch=$1 root=$2 t0=$SECONDS
  [ -e "$root/.uwms_debootstrap_done" ] && return
  unmount_all
  [ -e "$root" ] && { log "removing the unfinished root $root"; rm -rf --one-file-system "$root"; }
  if [ "$arch" = amd64 ]; then
    log "debootstrap $SUITE amd64 (minbase) from $MIRROR into $root"
    debootstrap --arch=amd64 --variant=minbase $SUITE "$root" "$MIRROR" > "$DIR/debootstrap-$arch.log" 2>&1 \
      || { tail -20 "$DIR/debootstrap-$arch.log" >&2; die "debootstrap $arch failed ($DIR/debootstrap-$arch.log)"; }
  else
    log "debootstrap $SUITE arm64 (minbase) from $MIRROR into $root (first stage, then the second under qemu)"
    debootstrap --arch=arm64 --variant=minbase --foreign $SUITE "$root" "$MIRROR" > "$DIR/debootstrap-$arch.log" 2>&1 \
      || { tail -20 "$DIR/debootstrap-$arch.log" >&2; die "debootstrap $arch failed ($DIR/debootstrap-$arch.log)"; }
    if ! grep -q '^flags:.*F' /proc/sys/fs/binfmt_misc/qemu-aarch64; then
      # Without binfmt's F flag the interpreter must be inside the root.
      interp=$(awk '/^interpreter/ { print $2 }' /proc/sys/fs/binfmt_misc/qemu-aarch64)
      install -D "$interp" "$root$interp"
    fi
    chroot "$root" /debootstrap/debootstrap --second-stage >> "$DIR/debootstrap-$arch.log" 2>&1 \
      || { tail -20 "$DIR/debootstrap-$arch.log" >&2; die "debootstrap --second-stage failed"; }
  fi
  touch "$root/.uwms_debootstrap_done"
  log "$arch root file system: $((SECONDS - t0)) s"
}

# unavailable ROOT PACKAGES... -> the names apt in ROOT has no candidate for (unknown, or only
# named by other packages), one a line
unavailable() {
  local root=$1 p; shift
  # Not "| grep -q": it may close the pipe before apt-cache ends, whose SIGPIPE pipefail reports.
  for p in "$@"; do [[ "$(in_root "$root" apt-cache policy "$p" 2>/dev/null)" == *"Candidate: "[^\(]* ]] || echo "$p"; done
}

install_in_root() {  # install_in_root ROOT NAME PACKAGES...: apt-get install once per package list
  local root=$1 name=$2 t0=$SECONDS; shift 2
  local stamp="$root/.uwms_packages_$name"
  if ! cmp -s <(printf '%s\n' "$@") "$stamp"; then
    log "apt-get install in the $name root: $*"
    # The lists anew: an archive's security updates replace packages (an old list's .deb is a 404).
    { in_root "$root" apt-get -qq update && in_root "$root" "${APT[@]}" install "$@" && in_root "$root" apt-get clean; } \
      > "$DIR/apt-$name.log" 2>&1 \
      || { tail -20 "$DIR/apt-$name.log" >&2; die "apt-get in the $name root failed ($DIR/apt-$name.log)"; }
    printf '%s\n' "$@" > "$stamp"
    log "$name packages: $((SECONDS - t0)) s"
  fi
}

apt_sources() {  # apt_sources ROOT: bullseye, its updates and security, then apt-get update (daily)
  local root=$1
  {
    echo "deb $MIRROR $SUITE main"
    echo "deb $MIRROR $SUITE-updates main"
    # No $SUITE-security: a build check needs no security fixes, and the archive this machine reaches
    # lists bullseye-security packages it does not serve (404).
  } > "$DIR/sources.list"
  cp /etc/resolv.conf "$root/etc/resolv.conf" 2>/dev/null || true
  if ! cmp -s "$DIR/sources.list" "$root/etc/apt/sources.list" || [ -z "$(find "$root/var/lib/apt/lists" \
    -maxdepth 1 -name '*Packages*' -mtime -1 2>/dev/null)" ]; then
    cp "$DIR/sources.list" "$root/etc/apt/sources.list"
    in_root "$root" apt-get -qq update > "$DIR/apt-update.log" 2>&1 || { tail "$DIR/apt-update.log" >&2; die "apt-get update failed"; }
  fi
}

# --- gtest counts (skipped and disabled tests count neither way) -------------------------------------
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
  if [ -s "$xml" ]; then
    read -r passed failed < <(python3 -c "$count_py" "$xml")
  else
    passed=$(grep -c '^\[       OK \]' "$logf" || true)
    failed=$(grep -c '^\[  FAILED  \] .* ms)$' "$logf" || true)
  fi
  if [ "$rc" -ne 0 ] && [ "$failed" -eq 0 ]; then
    tail -20 "$logf" >&2
    failed=1
  fi
  sed -n '/^\[==========\] .* ran\./,$p' "$logf" >&2
  [ "$failed" -eq 0 ] || status=1
  summary+=("platform_check: $what: $passed tests passed, $failed failed, run $((SECONDS - t0)) s")
}

# --- the amd64 root: always (the native build; for arm64, bullseye's cross compiler) --------------
ROS_PACKAGES=(catkin ros-core-dev libroscpp-dev libnodeletlib-dev libtf2-ros-dev libtf2-geometry-msgs-dev
  libimage-transport-dev libcv-bridge-dev libimage-geometry-dev libcamera-calibration-parsers-dev libroslib-dev
  librosbag-dev ros-message-generation ros-message-runtime ros-std-msgs ros-sensor-msgs ros-nav-msgs
  ros-geometry-msgs ros-visualization-msgs ros-diagnostic-msgs libdiagnostic-updater-dev python3-catkin-pkg
  python3-rospkg python3-roslaunch python3-rostest librostest-dev python3-rosbag)
CORE_PACKAGES=(build-essential cmake libopencv-dev libeigen3-dev libceres-dev libsqlite3-dev libyaml-cpp-dev
  libboost-dev libgtest-dev libgdal-dev python3)
t_setup=$SECONDS
make_root amd64 "$AMD"
apt_sources "$AMD"
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
    amd_packages+=("${ROS_PACKAGES[@]}")
  else
    mode=core
    log "bullseye lacks ${ros_missing[*]}: the ROS-free core, the simulator and test_core only"
  fi
  install_in_root "$AMD" amd64 "${amd_packages[@]}"
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

  # 1. The package (or the core) with bullseye's GCC 10, every SIFT it has.
  t0=$SECONDS
  set +e
  if [ "${UWMS_PLATFORM_PACKAGE:-1}" = 0 ]; then
    rc=skipped
  elif [ $mode = full ]; then
    # A fresh CMake cache each run (the objects stay): Debian 11's cmake-extras GMockConfig defines the
    # gmock_main target only when it is first found; a re-configure from the cache links a missing one.
    in_root "$AMD" bash -c "mkdir -p /ws/src && ln -sfn '$UWMS_REPO' /ws/src/uw_multislam && cd /ws && \
      rm -f build/CMakeCache.txt && \
      catkin_make -DPYTHON_EXECUTABLE=/usr/bin/python3 -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCATKIN_ENABLE_TESTING=ON \
        -DUWMS_WERROR=ON -j$JOBS && \
      make -C build -j$JOBS test_core test_conversions test_no_gdal" > "$DIR/build-amd64.log" 2>&1
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
      for t in test_core test_conversions test_no_gdal; do
        run_gtest "bullseye amd64 $t" "$AMD/ws/$t.xml" "$DIR/$t-amd64.log" \
          in_root "$AMD" bash -c "cd /ws && $bin/$t --gtest_output=xml:/ws/$t.xml $*"
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
  install_in_root "$AMD" amd64-cross cmake make g++-aarch64-linux-gnu python3
  make_root arm64 "$ARM"
  apt_sources "$ARM"
  # GeographicLib for the export library (test_core links it); no GDAL (optional: GeoTIFFs refused).
  arm_packages=(libc6-dev libopencv-dev libeigen3-dev libceres-dev libsqlite3-dev libyaml-cpp-dev libboost-dev libgtest-dev
    libgeographic-dev)
  [ -z "$(unavailable "$ARM" libvlfeat-dev)" ] && arm_packages+=(libvlfeat-dev)
  if ! cmp -s <(printf '%s\n' "${arm_packages[@]}") "$ARM/.uwms_packages_arm64"; then
    unmount_all
    install_in_root "$ARM" arm64 "${arm_packages[@]}"
    unmount_all
    # Absolute symlinks (update-alternatives' libblas.so.3 -> /etc/alternatives/...) would resolve in
    # the amd64 root when this root is its /sysroot: made relative, they resolve the same anywhere.
    n=0
    while IFS= read -r -d '' l; do
      t=$(readlink "$l")
      ln -sfn "$(realpath -s -m --relative-to="$(dirname "$l")" "$ARM$t")" "$l"
      n=$((n + 1))
    done < <(find "$ARM" -xdev -type l -lname '/*' ! -path "$ARM/proc/*" ! -path "$ARM/dev/*" -print0)
    log "$n absolute symlinks in the arm64 root made relative"
    bind_ro "$UWMS_REPO" "$AMD$UWMS_REPO"
  fi
  setup_s=$((setup_s + SECONDS - t0))
  bind_ro "$ARM" "$AMD/sysroot"
  versions=$(in_root "$ARM" dpkg-query -W -f='${Package} ${Version}\n' libopencv-dev libceres-dev libeigen3-dev \
    libvlfeat-dev 2>/dev/null | tr '\n' ';' || true)
  log "bullseye arm64: $versions; cross: $(in_root "$AMD" aarch64-linux-gnu-g++ --version | head -1)"
  cat > "$DIR/aarch64-toolchain.cmake.new" <<EOF
# Written by scripts/platform_check.sh: bullseye's cross compiler, the bullseye arm64 root as sysroot.
set(CMAKE_SYSTEM_NAME Linux)
set(CMAKE_SYSTEM_PROCESSOR aarch64)
set(CMAKE_C_COMPILER aarch64-linux-gnu-gcc)
set(CMAKE_CXX_COMPILER aarch64-linux-gnu-g++)
set(CMAKE_LIBRARY_ARCHITECTURE aarch64-linux-gnu)
set(CMAKE_SYSROOT /sysroot)
set(CMAKE_FIND_ROOT_PATH /sysroot)
set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_PACKAGE ONLY)
EOF
  mkdir -p "$AMD/build"
  cmp -s "$DIR/aarch64-toolchain.cmake.new" "$AMD/build/aarch64-toolchain.cmake" && rm "$DIR/aarch64-toolchain.cmake.new" \
    || mv "$DIR/aarch64-toolchain.cmake.new" "$AMD/build/aarch64-toolchain.cmake"
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
