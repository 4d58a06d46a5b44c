#!/usr/bin/env bash
# The demo command: installs what is missing, builds, generates the built-in two-session survey
# (procedural seabed; the second mission dimmer, bluer, turned 90 degrees), runs offline_slam
# over both sessions and scores the run against the ground truth with evaluate.py (metrics
# table and trajectory plots). Loop detection and map joining join this run as they land.
# Environment: UWMS_DEMO_OUT (default <repo>/out/demo).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"

bash "$UWMS_REPO/scripts/install_deps.sh"
bash "$UWMS_REPO/scripts/build.sh"
bin="$UWMS_WS/devel/lib/uw_multislam"
out=${UWMS_DEMO_OUT:-$UWMS_REPO/out/demo}

echo "[demo] core self-check"
"$bin/self_check" | tail -n 1
echo "[demo] generating the two-session demo survey into $out/survey"
"$bin/make_survey" --preset demo --out "$out/survey" --quiet
echo "[demo] offline_slam over both sessions into $out/run"
"$bin/offline_slam" --session "$out/survey/s0" --session "$out/survey/s1" --out "$out/run"
echo "[demo] scoring the run against the ground truth"
/usr/bin/python3 "$UWMS_REPO/src/tools/evaluate.py" --run "$out/run" --mission "$out/survey" --report "$out/report"
echo "[demo] done: survey in $out/survey, run in $out/run, metrics and plots in $out/report"
