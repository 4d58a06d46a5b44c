#!/usr/bin/env bash
# Renders an evaluate.py --html report in a real headless browser (Chromium, from Debian; installed
# here with apt-get when missing) and saves a screenshot. Without a report it first runs the
# offline demo (scripts/demo.sh --offline), whose report is out/demo/offline_report/report.html.
# It checks what the browser loaded: every figure decoded (the page's images have a width), and
# the tables are there; a report that does not render fails with the reason.
#
#   bash scripts/report_screenshot.sh [REPORT.html] [OUT.png]   # default: the offline demo -> doc/report.png
#
# Not part of CI (Chromium is a large install); test/python/test_evaluate.py checks the HTML itself.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"

html=${1:-}
png=${2:-$UWMS_REPO/doc/report.png}
if [ -z "$html" ]; then
  bash "$UWMS_REPO/scripts/demo.sh" --offline
  html="${UWMS_DEMO_OUT:-$UWMS_REPO/out/demo}/offline_report/report.html"
fi
[ -f "$html" ] || { echo "report_screenshot: $html: no such report (evaluate.py --html writes report.html)" >&2; exit 1; }
if ! command -v chromium >/dev/null; then
  echo "[report_screenshot] installing chromium (Debian)"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO=sudo
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq chromium >/tmp/uw_multislam_chromium.log 2>&1 || {
    tail -n 20 /tmp/uw_multislam_chromium.log >&2; exit 1; }
fi
url="file://$(readlink -f "$html")"
flags=(--headless --no-sandbox --disable-gpu --hide-scrollbars --no-first-run --user-data-dir="$(mktemp -d)")
# What the browser made of the page: after loading, a script writes each image's decoded width and
# the number of tables into the title (--dump-dom prints the DOM after the page's scripts ran).
probe=$(mktemp --suffix=.html)
trap 'rm -f "$probe"' EXIT
{ cat "$html"; echo '<script>document.title = "probe " + Array.from(document.images).map(i => i.naturalWidth).join(",") +
  " tables " + document.getElementsByTagName("table").length;</script>'; } > "$probe"
title=$(timeout 120 chromium "${flags[@]}" --dump-dom "file://$probe" 2>/dev/null | grep -o '<title>probe [^<]*' | sed 's/<title>//')
echo "[report_screenshot] rendered: $title"
read -r _ widths _ tables <<<"$title"
[ -n "$widths" ] || { echo "report_screenshot: the page shows no figure" >&2; exit 1; }
case ",$widths," in *,0,*) echo "report_screenshot: a figure did not decode (widths $widths)" >&2; exit 1 ;; esac
[ "${tables:-0}" -gt 0 ] || { echo "report_screenshot: the page shows no table" >&2; exit 1; }
mkdir -p "$(dirname "$png")"
timeout 120 chromium "${flags[@]}" --screenshot="$png" --window-size=1200,1500 "$url" 2>/dev/null
echo "[report_screenshot] $png ($(identify -format '%wx%h' "$png" 2>/dev/null || echo '?'))"
