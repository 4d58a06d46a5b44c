// The loop-detector nodelet's counters (/diagnostics status "<node>: loop_detector", and its
// periodic and shutdown log lines): one field each, named once in loopDetectorCounterTable() with
// its help text; doc/diagnostics.md documents them and test/ros/test_diagnostics.cpp checks it.
#pragma once

#include "uw_multislam/core/loops/loop_detector.h"
#include "uw_multislam/ros/diagnostics.h"

namespace uw_multislam {
namespace ros_diagnostics {

struct LoopDetectorCounters {
  long keyframes_received = 0, dropped_queue_full = 0, queue_length = 0, skipped_bad_keyframe = 0;
  long keyframe_id_gaps = 0, sessions = 0, keyframes_stored = 0, local_candidates = 0, global_candidates = 0;
  long local_loops = 0, global_loops = 0, hashes = 0;
  long keyframes_reloaded = 0, keyframes_reloaded_again = 0, sessions_unloaded = 0, keyframes_unloaded = 0;
  long keyframes_paged = 0, keyframes_paged_live = 0, foreign_keyframes = 0, foreign_loops = 0;
  long feature_cache_hits = 0, feature_cache_misses = 0;
  double feature_cache_mb = 0.0;
  long feature_read_failures = 0;
  double ms_per_keyframe_mean = 0.0, ms_per_keyframe_max = 0.0;

  double total_ms = 0.0;  // not published: the time of the keyframes received
};

const CounterTable<LoopDetectorCounters>& loopDetectorCounterTable();

/// The detector's own counts (candidates, keyframes held, the feature cache) into `c`; the
/// detector's thread only.
void setDetectorCounters(const core::LoopDetector& detector, LoopDetectorCounters* c);

}  // namespace ros_diagnostics
}  // namespace uw_multislam
