#!/usr/bin/env bash
# Bounded latency: a camera faster than the odometry. A generated 10 Hz mission is published live
# (each frame stamped when sent, scripts/bench_load_drive.py) through slam.launch (one nodelet
# manager, no store, its own master), a fresh pipeline per run:
#   1. every frame (~drop_policy oldest, a queue of 10000) at the mission's 10 Hz, which the
#      odometry keeps up with: the reference sessions and keyframes;
#   2. the calibration: newest at twice the rate that reference's ms per frame sustains. A frame
#      costs less in a busy pipeline than in one fed at 10 Hz (caches and clock run cold there),
#      so the sustainable rate is the inverse of the cost measured here (both printed);
#   3. at each multiple of the sustainable rate (default 2 and 4), the former drop-oldest queue
#      (~drop_policy oldest, ~queue_size 5), newest taking its choice at once with the keyframe rule
#      as it is (~stale_fraction 1, ~keyframe_lookahead false: the policy before both), the
#      bounded-latency policy (newest, the default: it waits for the next frame rather than start a
#      stale one, and makes keyframes ahead of frames that would wait),
#      newest with one thread preparing each frame as it arrives (~prepare_threads 1), and with
#      --nice N both again with the loop detector's and back-end's workers at nice N (worker_nice).
# Each row: the latency from image stamp to odometry/pose (median, p99, in ms and input periods),
# frames skipped and dropped, sessions and tracking losses (against the reference: no extra
# split), keyframes, the CPU the driver itself took (it shares the machine), the load average,
# how far behind the odometry really was, the waits for a fresher frame and the time-averaged age
# of the newest pose received (waiting must lower it, not only the latency). The bar: newest at
# 2x, p99 <= 3 input periods and no extra session.
# Not a test: numbers for this machine (doc/benchmarks/load.md).
# usage: scripts/bench_load.sh [--multiples "2 4"] [--nice N] [--size WxH] [--length M] [OUT_DIR]
#   --size: the camera (default 680x512, the acfr camera's: a frame costs ~50 ms here, so the input period at 2x
#   is ~25 ms, well above this machine's scheduling noise; 320x240 costs ~15 ms, a period of ~7.5 ms at 2x, where
#   a few ms of noise is a large part of it: the stress case); --length: the lawnmower's legs, m (default 8).
# The earlier rate sweep (rates, drops, RSS, pose gap) is scripts/bench_load_sweep.sh.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/bench_load_common.sh"
multiples="2 4"
nice=0
size=680x512
length=8
while [ $# -gt 0 ]; do
  case "$1" in
    --multiples) multiples=$2; shift 2 ;;
    --nice) nice=$2; shift 2 ;;
    --size) size=$2; shift 2 ;;
    --length) length=$2; shift 2 ;;
    *) break ;;
  esac
done
bench_init bench_load 11392 "${1:-}"

width=${size%x*}; height=${size#*x}
focal=$(awk -v w="$width" 'BEGIN { printf "%.1f", w * 300 / 320 }')  # the demo camera's field of view
if [ ! -f "$out/mission/s0.bag" ]; then
  cat > "$out/survey.yaml" << EOF
seed: 3
world: {width_m: 16, height_m: 12, featureless_fraction: 0.0}
sessions:
  - name: s0
    camera: {image_width: $width, image_height: $height, fx: $focal, fy: $focal, cx: $(( width / 2 )).5, cy: $(( height / 2 )).5}
    mission: {pattern: lawnmower, start_m: [3, 3], length_m: $length, width_m: 4.2, leg_spacing_m: 1.4, laps: 1.0,
              speed_m_s: 0.5, frame_period_s: 0.1, altitude_m: 2.5, start_time_s: 0}
EOF
  log "make_survey --config $out/survey.yaml"
  "$bin/make_survey" --config "$out/survey.yaml" --out "$out/mission" --quiet > /dev/null
fi
bag="$out/mission/s0.bag"

bench_roscore

run() {  # name rate odometry_node key=value... -> JSON line in $out/<name>.json
  local name=$1 rate=$2
  shift 2
  bench_config "$out/config_$name.yaml" "$@"
  bench_launch "$out/launch_$name.log" "$out/config_$name.yaml"
  /usr/bin/python3 "$UWMS_REPO/scripts/bench_load_drive.py" "$bag" "$rate" > "$out/$name.json" 2> "$out/drive_$name.log" \
    || echo '{"error": "the driver failed"}' > "$out/$name.json"
  bench_stop
  log "$name: $(cat "$out/$name.json")"
}

log "reference: every frame at 10 Hz"
run reference 10 drop_policy=oldest queue_size=10000 prepare_threads=0
ms_of() { /usr/bin/python3 -c 'import json,sys; print("%.2f" % json.load(open(sys.argv[1]))["ms_per_frame_mean"])' "$1"; }
rate=$(awk -v c="$(ms_of "$out/reference.json")" 'BEGIN { printf "%.1f", 2 * 1000 / c }')
log "calibration: newest at $rate frames/s (twice the reference's), a frame's cost in a busy pipeline"
run calibration "$rate" drop_policy=newest queue_size=5 prepare_threads=0
sustainable=$(awk -v c="$(ms_of "$out/calibration.json")" 'BEGIN { printf "%.1f", 1000 / c }')
policies="oldest newest_now newest prepare"
[ "$nice" -gt 0 ] && policies="$policies newest_nice prepare_nice"
for m in $multiples; do
  rate=$(awk -v s="$sustainable" -v m="$m" 'BEGIN { printf "%.1f", s * m }')
  run "oldest_${m}x" "$rate" drop_policy=oldest queue_size=5 prepare_threads=0
  run "newest_now_${m}x" "$rate" drop_policy=newest queue_size=5 prepare_threads=0 stale_fraction=1 keyframe_lookahead=false
  run "newest_${m}x" "$rate" drop_policy=newest queue_size=5 prepare_threads=0
  run "prepare_${m}x" "$rate" drop_policy=newest queue_size=5 prepare_threads=1
  if [ "$nice" -gt 0 ]; then
    yielding="loop_detector_node/worker_nice=$nice backend_node/worker_nice=$nice"
    # shellcheck disable=SC2086  # two key=value words
    run "newest_nice_${m}x" "$rate" drop_policy=newest queue_size=5 prepare_threads=0 $yielding
    # shellcheck disable=SC2086
    run "prepare_nice_${m}x" "$rate" drop_policy=newest queue_size=5 prepare_threads=1 $yielding
  fi
done

/usr/bin/python3 - "$out" "$sustainable" "$size" "$(git -C "$UWMS_REPO" rev-parse --short HEAD 2> /dev/null || echo unknown)" \
  "$nice" $multiples << 'PY'
import json, os, sys
out, sustainable, size, commit = sys.argv[1], float(sys.argv[2]), sys.argv[3], sys.argv[4]
nice, multiples = int(sys.argv[5]), sys.argv[6:]
ref = json.load(open(os.path.join(out, "reference.json")))
cal = json.load(open(os.path.join(out, "calibration.json")))
print("### Bounded latency: %d frames of %s at 10 Hz (a generated lawnmower), slam.launch, %s, commit %s, "
      "load average %.1f at the start" % (ref["frames"], size, os.popen("date -u '+%F %H:%M UTC'").read().strip(),
                                          commit, ref.get("load_average", float("nan"))))
print()
print("Reference, every frame at 10 Hz (drop_policy oldest, queue 10000): %d processed, %d sessions, %d tracking "
      "losses, %d keyframes, %.1f ms per frame. Calibration, newest at %.1f frames/s: %.1f ms per frame in a busy "
      "pipeline: sustainable rate %.1f frames/s." % (
          ref["frames_processed"], ref["sessions"], ref["tracking_losses"], ref["keyframes"], ref["ms_per_frame_mean"],
          cal["rate_hz"], cal["ms_per_frame_mean"], sustainable))
print()
print("| policy | rate | frames/s | behind | processed | prepared on arrival | skipped for newest | dropped (queue full, or no prediction) "
      "| not received | sessions | tracking losses | keyframes | driver CPU | load average "
      "| latency median ms (periods) | latency p99 ms (periods) | p99 ms: keyframes / others "
      "| waits for fresher | early keyframes | mean pose age ms (periods) |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
names = {"oldest": "oldest (queue 5, former)", "newest_now": "newest, no wait, no lookahead (before)", "newest": "newest", "prepare": "newest, prepare_threads 1",
         "newest_nice": "newest, loops and back-end at nice %d" % nice,
         "prepare_nice": "newest, prepare_threads 1, loops and back-end at nice %d" % nice}
policies = ["oldest", "newest_now", "newest", "prepare"] + (["newest_nice", "prepare_nice"] if nice > 0 else [])
verdict = []
for m in multiples:
    rows = {}
    for policy in policies:
        rows[policy] = json.load(open(os.path.join(out, "%s_%sx.json" % (policy, m))))
    # How far behind the camera the odometry really was: the offered rate times a frame's cost in
    # that very run (the machine is shared: its load moves between the calibration and the rows).
    # A worker that is behind is never idle, so its mean ms per frame is that cost; with a
    # preparing thread it is not (the features come from the other core): that row is given the
    # cost of the row without one run just before it.
    cost = {p: rows[p].get("ms_per_frame_mean") for p in policies}
    cost["prepare"] = cost["newest"]
    if nice > 0:
        cost["prepare_nice"] = cost["newest_nice"]
    for policy in policies:
        r = rows[policy]
        if "error" in r:
            print("| %s | %sx | (%s) |" % (names[policy], m, r["error"]))
            continue
        behind = r["rate_hz"] * (cost[policy] or float("nan")) / 1000.0
        print("| %s | %sx | %.1f | %.1fx%s | %d | %d | %d | %d | %d | %d | %d | %d | %.0f %% | %.1f | %.0f (%.1f) "
              "| %.0f (%.1f) | %.0f / %.0f | %d | %d | %.0f (%.1f) |" % (
                  names[policy], m, r["rate_hz"], behind, "*" if policy.startswith("prepare") else "",
                  r["frames_processed"], r["prepared_ahead"], r["skipped_for_newest"], r["dropped_queue_full"],
                  r["frames"] - r["images_received"], r["sessions"], r["tracking_losses"], r["keyframes"],
                  100 * r["driver_cpu"], r["load_average"], r["latency_median_ms"], r["latency_median_periods"],
                  r["latency_p99_ms"], r["latency_p99_periods"], r.get("latency_p99_keyframes_ms", float("nan")),
                  r.get("latency_p99_others_ms", float("nan")), r.get("waits_for_fresher", 0),
                  r.get("early_keyframes", 0), r.get("pose_age_mean_ms", float("nan")),
                  r.get("pose_age_mean_periods", float("nan"))))
        if policy not in ("oldest", "newest_now") and m == "2":
            ok = r["latency_p99_periods"] <= 3.0 and r["sessions"] <= ref["sessions"]
            verdict.append("%s at 2x (%.1fx behind): p99 %.1f input periods (bar: <= 3; the former queue %.1f), %d "
                           "sessions (every frame: %d): %s%s" % (
                               names[policy], behind, r["latency_p99_periods"],
                               rows["oldest"].get("latency_p99_periods", float("nan")), r["sessions"], ref["sessions"],
                               "meets the bar" if ok else "MISSES the bar",
                               "" if 1.8 <= behind <= 2.2 else " (not a true 2x: the load moved since the calibration)"))
print()
print("behind: the offered rate times a frame's cost in the same run (* that of the row without a preparing thread "
      "before it). not received: frames sent that never reached the odometry (its subscriber's queue). "
      "keyframes / others: the p99 of the poses of the frames that became keyframes, and of the rest.")
print()
for v in verdict:
    print(v)
PY
echo "(logs and JSON in $out)"
