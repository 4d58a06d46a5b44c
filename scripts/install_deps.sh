#!/usr/bin/env bash
# Installs the Debian 12 packages uw_multislam needs to build, test and run.
# Idempotent: when everything is already installed it prints one line and returns.
set -euo pipefail

PACKAGES=(
  build-essential cmake git
  catkin ros-core-dev libroscpp-dev libnodeletlib-dev libnodeletlib-tools
  libtf2-ros-dev libtf2-geometry-msgs-dev libimage-transport-dev libcv-bridge-dev
  libimage-geometry-dev libcamera-calibration-parsers-dev libroslib-dev
  librosbag-dev python3-rosbag libboost-dev libboost-program-options-dev python3-catkin-pkg python3-rospkg
  ros-message-generation ros-message-runtime ros-std-msgs ros-sensor-msgs ros-nav-msgs ros-geometry-msgs
  ros-visualization-msgs ros-diagnostic-msgs libdiagnostic-updater-dev python3-diagnostic-msgs
  python3-roslaunch python3-rostest librostest-dev rosbash python3-rostopic python3-rosservice
  libopencv-dev libeigen3-dev libceres-dev libsqlite3-dev libgtest-dev libyaml-cpp-dev
  libgeographiclib-dev libgdal-dev python3-gdal python3-pil
  libvlfeat-dev
  python3-nodelet python3-rosnode python3-tf2-ros python3-tf2-msgs python3-geometry-msgs python3-sensor-msgs python3-nav-msgs python3-visualization-msgs python3-numpy python3-matplotlib python3-yaml python3-pytest bc
  topic-tools libimage-proc-dev python3-std-srvs
  rviz xvfb imagemagick clang-format clang
)

missing=()
for p in "${PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "[install_deps] all ${#PACKAGES[@]} packages already installed"
  exit 0
fi

SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi

echo "[install_deps] installing ${#missing[@]} missing packages: ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/tmp/uw_multislam_apt.log 2>&1 || {
  echo "[install_deps] apt-get install failed; last lines of /tmp/uw_multislam_apt.log:" >&2
  tail -n 30 /tmp/uw_multislam_apt.log >&2
  exit 1
}
echo "[install_deps] done"
