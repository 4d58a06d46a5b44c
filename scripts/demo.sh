#!/usr/bin/env bash
# The demo command: installs what is missing, builds, generates the built-in two-session survey
# (procedural seabed, second mission dimmer, bluer, turned 90 degrees) into out/demo and runs
# the core self-check. The SLAM run over that survey joins this script as the pipeline lands.
# Environment: UWMS_DEMO_OUT (default <repo>/out/demo).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"

bash "$UWMS_REPO/scripts/install_deps.sh"
bash "$UWMS_REPO/scripts/build.sh"
bin="$UWMS_WS/devel/lib/uw_multislam"
out=${UWMS_DEMO_OUT:-$UWMS_REPO/out/demo}

echo "[demo] generating the demo survey into $out"
"$bin/make_survey" --preset demo --out "$out/survey" --quiet
echo "[demo] core self-check"
"$bin/self_check"
echo "[demo] done: dataset folders, bags and ground truth in $out/survey"
