#!/usr/bin/env bash
# The demo command: installs what is missing, builds, and runs uw_multislam's main job on
# built-in data. For now that is the core self-check (tools/self_check); the SLAM demo on a
# generated two-session survey replaces it as the pipeline lands.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"

bash "$UWMS_REPO/scripts/install_deps.sh"
bash "$UWMS_REPO/scripts/build.sh"
"$UWMS_WS/devel/lib/uw_multislam/self_check" "$@"
