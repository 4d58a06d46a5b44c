# shellcheck shell=bash
# Debian root file systems for the checks that build and test beside the host's own Debian:
# scripts/arm64_check.sh (a bookworm arm64 root as sysroot and qemu -L prefix) and
# scripts/platform_check.sh (bullseye amd64 and arm64 roots). Sourced, not run; the caller runs as
# root, under `set -euo pipefail`, and defines log MESSAGE and die MESSAGE (its own prefix).
#
#   host_install LOG PACKAGES...            apt-get install on the host what is not installed yet
#   binfmt_arm64                            arm64 binaries run through qemu (binfmt_misc); prints
#                                           yes when registered with the F flag, else no
#   host_uri SUITE                          the Debian mirror the host's apt uses for SUITE, else for
#                                           any suite, else deb.debian.org (only the host's archive
#                                           may be reachable)
#   unmount_below DIR                       every mount below DIR, deepest first (for a trap)
#   in_root ROOT COMMAND...                 a command in ROOT with its own /proc and a read-only /sys
#   bind_ro SOURCE TARGET                   a read-only bind mount, once
#   make_root ARCH SUITE ROOT MIRROR LOG    debootstrap --variant=minbase, once (a stamp file says
#                                           it finished; an unfinished root is removed first);
#                                           another architecture's second stage runs under qemu
#   root_sources ROOT FILE                  FILE (an apt sources.list) into ROOT, the host's
#                                           resolv.conf (and hosts, if ROOT has none), and apt-get update when FILE changed or
#                                           the lists are a day old
#   root_install ROOT STAMP LOG PACKAGES... apt-get update and install in ROOT, then clean, unless
#                                           STAMP already holds this package list
#   relative_symlinks ROOT                  ROOT's absolute symlinks made relative
#   aarch64_toolchain FILE SYSROOT [EMU...] a CMake toolchain file for aarch64-linux-gnu-g++ with
#                                           SYSROOT, rewritten only when it changes
#   gtest_counts XML LOG                    "passed failed" of one gtest run
DEBIAN_ROOT_APT=(apt-get -o DPkg::Lock::Timeout=900 -y -qq --no-install-recommends)
export DEBIAN_FRONTEND=noninteractive

host_install() {
  local logf=$1 p missing=()
  shift
  for p in "$@"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  [ ${#missing[@]} -eq 0 ] && return
  log "installing on the host: ${missing[*]}"
  { "${DEBIAN_ROOT_APT[@]}" install "${missing[@]}" \
    || { apt-get -o DPkg::Lock::Timeout=900 -qq update && "${DEBIAN_ROOT_APT[@]}" install "${missing[@]}"; }; } \
    > "$logf" 2>&1 || { tail -20 "$logf" >&2; die "host apt-get install failed ($logf)"; }
}

binfmt_arm64() {
  local binfmt=/proc/sys/fs/binfmt_misc
  [ -e $binfmt/register ] || mount -t binfmt_misc binfmt_misc $binfmt \
    || die "cannot mount binfmt_misc on $binfmt (a container without it cannot run an arm64 root)"
  [ -e $binfmt/qemu-aarch64 ] || update-binfmts --enable qemu-aarch64 >&2 \
    || die "update-binfmts --enable qemu-aarch64 failed"
  grep -q '^enabled' $binfmt/qemu-aarch64 || die "$binfmt/qemu-aarch64 is disabled"
  # Debian registers it with the F flag (the interpreter opened at registration, so it works in a
  # chroot); without it the interpreter must be inside the root too.
  if grep -q '^flags:.*F' $binfmt/qemu-aarch64; then echo yes; else echo no; fi
}

host_uri() {
  local suite=$1 uri
  # One-line sources (deb [options] URI SUITE ...), then deb822 stanzas whose Suites name SUITE.
  uri=$(cat /etc/apt/sources.list /etc/apt/sources.list.d/*.list 2>/dev/null | awk -v s="$suite" '
    $1 == "deb" { i = 2; if ($2 ~ /^\[/) { while (i < NF && $i !~ /\]$/) i++; i++ }
                  if ($(i + 1) == s) { print $i; exit } }')
  [ -n "$uri" ] || uri=$(cat /etc/apt/sources.list.d/*.sources 2>/dev/null | awk -v s="$suite" '
    function flush() { if (deb && has && u != "" && !done) { print u; done = 1 } deb = has = 0; u = "" }
    /^[ \t]*$/ { flush(); next }
    /^Types:/ { for (i = 2; i <= NF; i++) if ($i == "deb") deb = 1 }
    /^URIs:/ { u = $2 }
    /^Suites:/ { for (i = 2; i <= NF; i++) if ($i == s) has = 1 }
    END { flush() }')
  # Another suite than the host's own: the same archive (a URI ending in debian), whatever it serves.
  [ -n "$uri" ] || uri=$(cat /etc/apt/sources.list /etc/apt/sources.list.d/*.list 2>/dev/null | awk '
    $1 == "deb" { i = 2; if ($2 ~ /^\[/) { while (i < NF && $i !~ /\]$/) i++; i++ }
                  if ($i ~ /debian\/?$/) { print $i; exit } }')
  [ -n "$uri" ] || uri=$(cat /etc/apt/sources.list.d/*.sources 2>/dev/null | awk '
    /^URIs:/ { for (i = 2; i <= NF; i++) if ($i ~ /debian\/?$/) { print $i; exit } }')
  echo "${uri:-http://deb.debian.org/debian}"
}

unmount_below() {
  local m
  for m in $(awk -v r="$1/" 'index($5, r) == 1 { print $5 }' /proc/self/mountinfo | sort -r); do
    umount "$m" 2>/dev/null || umount -l "$m" || true
  done
}

in_root() {
  local root=$1
  shift
  mountpoint -q "$root/proc" || mount -t proc proc "$root/proc"
  # As on a real system, /sys is not writable (a store test expects a path there to be refused).
  mountpoint -q "$root/sys" || mount -t sysfs -o ro sysfs "$root/sys"
  chroot "$root" /usr/bin/env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin HOME=/root DEBIAN_FRONTEND=noninteractive \
    LC_ALL=C "$@"
}

bind_ro() {
  mkdir -p "$2"
  mountpoint -q "$2" || { mount --bind "$1" "$2" && mount -o remount,bind,ro "$2"; }
}

make_root() {
  local arch=$1 suite=$2 root=$3 mirror=$4 logf=$5 t0=$SECONDS interp
  [ -e "$root/.uwms_debootstrap_done" ] && return
  unmount_below "$root"
  [ -e "$root" ] && { log "removing the unfinished root $root"; rm -rf --one-file-system "$root"; }
  if [ "$arch" = "$(dpkg --print-architecture)" ]; then
    log "debootstrap $suite $arch (minbase) from $mirror into $root"
    debootstrap --arch="$arch" --variant=minbase "$suite" "$root" "$mirror" > "$logf" 2>&1 \
      || { tail -20 "$logf" >&2; die "debootstrap $arch failed ($logf)"; }
  else
    log "debootstrap $suite $arch (minbase) from $mirror into $root (first stage, then the second under qemu)"
    debootstrap --arch="$arch" --variant=minbase --foreign "$suite" "$root" "$mirror" > "$logf" 2>&1 \
      || { tail -20 "$logf" >&2; die "debootstrap $arch failed ($logf)"; }
    if [ "$(binfmt_arm64)" = no ]; then
      interp=$(awk '/^interpreter/ { print $2 }' /proc/sys/fs/binfmt_misc/qemu-aarch64)
      install -D "$interp" "$root$interp"
      install -D /usr/bin/qemu-aarch64-static "$root/usr/bin/qemu-aarch64-static"
    fi
    chroot "$root" /debootstrap/debootstrap --second-stage >> "$logf" 2>&1 \
      || { tail -20 "$logf" >&2; die "debootstrap --second-stage failed ($logf)"; }
  fi
  touch "$root/.uwms_debootstrap_done"
  log "$arch root file system: $((SECONDS - t0)) s"
}

root_sources() {
  local root=$1 file=$2 logf
  logf=$(dirname "$file")/apt-update.log
  cp /etc/resolv.conf "$root/etc/resolv.conf" 2>/dev/null || true
  # debootstrap writes no /etc/hosts: without it "localhost" does not resolve (ROS nodes, tests).
  [ -e "$root/etc/hosts" ] || cp /etc/hosts "$root/etc/hosts" 2>/dev/null || true
  if ! cmp -s "$file" "$root/etc/apt/sources.list" || [ -z "$(find "$root/var/lib/apt/lists" \
    -maxdepth 1 -name '*Packages*' -mtime -1 2>/dev/null)" ]; then
    cp "$file" "$root/etc/apt/sources.list"
    in_root "$root" apt-get -qq update > "$logf" 2>&1 || { tail "$logf" >&2; die "apt-get update in $root failed"; }
  fi
}

root_install() {
  local root=$1 stamp=$2 logf=$3 t0=$SECONDS
  shift 3
  cmp -s <(printf '%s\n' "$@") "$stamp" && return
  log "apt-get install in $root: $*"
  # The lists anew: an archive's updates replace packages (an old list's .deb is a 404).
  { in_root "$root" apt-get -qq update && in_root "$root" "${DEBIAN_ROOT_APT[@]}" install "$@" \
    && in_root "$root" apt-get clean; } > "$logf" 2>&1 \
    || { tail -20 "$logf" >&2; die "apt-get in $root failed ($logf)"; }
  printf '%s\n' "$@" > "$stamp"
  log "packages in $root: $((SECONDS - t0)) s"
}

relative_symlinks() {
  # Absolute symlinks (update-alternatives' libblas.so.3 -> /etc/alternatives/... -> ...) would point
  # into the host when the root is a sysroot (the linker) or a qemu -L prefix (the loader): made
  # relative, they resolve the same in the chroot and from outside it.
  local root=$1 l t n=0
  unmount_below "$root"
  while IFS= read -r -d '' l; do
    t=$(readlink "$l")
    ln -sfn "$(realpath -s -m --relative-to="$(dirname "$l")" "$root$t")" "$l"
    n=$((n + 1))
  done < <(find "$root" -xdev -type l -lname '/*' ! -path "$root/proc/*" ! -path "$root/dev/*" -print0)
  log "$n absolute symlinks in $root made relative"
}

aarch64_toolchain() {
  local file=$1 sysroot=$2
  shift 2
  {
    echo "# Written by scripts/debian_root.sh for $(basename "$0"): aarch64-linux-gnu-g++, $sysroot as sysroot."
    echo "set(CMAKE_SYSTEM_NAME Linux)"
    echo "set(CMAKE_SYSTEM_PROCESSOR aarch64)"
    echo "set(CMAKE_C_COMPILER aarch64-linux-gnu-gcc)"
    echo "set(CMAKE_CXX_COMPILER aarch64-linux-gnu-g++)"
    echo "set(CMAKE_LIBRARY_ARCHITECTURE aarch64-linux-gnu)"
    echo "set(CMAKE_SYSROOT \"$sysroot\")"
    echo "set(CMAKE_FIND_ROOT_PATH \"$sysroot\")"
    echo "set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)"
    echo "set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)"
    echo "set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE ONLY)"
    echo "set(CMAKE_FIND_ROOT_PATH_MODE_PACKAGE ONLY)"
    [ $# -eq 0 ] || echo "set(CMAKE_CROSSCOMPILING_EMULATOR $*)"
  } > "$file.new"
  mkdir -p "$(dirname "$file")"
  if cmp -s "$file.new" "$file"; then rm "$file.new"; else mv "$file.new" "$file"; fi
}

# Counted from gtest's XML, skipped and disabled tests neither way; without an XML (the binary died
# before its end) from the tests its log says finished.
gtest_counts() {
  local xml=$1 logf=$2
  if [ -s "$xml" ]; then
    python3 -c '
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
print(passed, failed)' "$xml"
  else
    echo "$(grep -c '^\[       OK \]' "$logf" || true) $(grep -c '^\[  FAILED  \] .* ms)$' "$logf" || true)"
  fi
}
