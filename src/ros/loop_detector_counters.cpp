#include "uw_multislam/ros/loop_detector_counters.h"

namespace uw_multislam {
namespace ros_diagnostics {

const CounterTable<LoopDetectorCounters>& loopDetectorCounterTable() {
  using C = LoopDetectorCounters;
  constexpr bool kWarn = true;  // a drop, a bad keyframe or a gap: the status WARNs while it grows
  static const CounterTable<C> table = {
      {"keyframes_received", &C::keyframes_received, "live keyframes taken by the worker"},
      {"dropped_queue_full", &C::dropped_queue_full,
       "keyframes the worker's FIFO dropped when full (the oldest; never a loop candidate)", kWarn},
      {"queue_length", &C::queue_length, "keyframes waiting in the worker's FIFO"},
      {"skipped_bad_keyframe", &C::skipped_bad_keyframe,
       "keyframes skipped: unreadable, repeated or out of order, an id past ~max_keyframe_gap, or an id of another "
       "vehicle's session",
       kWarn},
      {"keyframe_id_gaps", &C::keyframe_id_gaps, "gaps in the keyframe ids, bridged by odometry poses", kWarn},
      {"sessions", &C::sessions, "sessions known"},
      {"keyframes_stored", &C::keyframes_stored, "keyframes held as loop candidates"},
      {"local_candidates", &C::local_candidates, "local loop candidates verified (paper section 6)"},
      {"global_candidates", &C::global_candidates, "global loop candidates verified (paper section 7)"},
      {"local_loops", &C::local_loops, "local loops published"},
      {"global_loops", &C::global_loops, "global loops published"},
      {"hashes", &C::hashes, "keyframe hashes published (mode global or both)"},
      {"keyframes_reloaded", &C::keyframes_reloaded, "stored keyframes taken from reloaded_keyframes"},
      {"keyframes_reloaded_again", &C::keyframes_reloaded_again, "stored keyframes sent again and held already"},
      {"sessions_unloaded", &C::sessions_unloaded, "sessions forgotten (unload_session)"},
      {"keyframes_unloaded", &C::keyframes_unloaded, "keyframes forgotten with them"},
      {"keyframes_paged", &C::keyframes_paged, "stored keyframes held as hash and ids only (slam/loops/page_stored)"},
      {"keyframes_paged_live", &C::keyframes_paged_live,
       "live keyframes paged out behind their session (slam/loops/page_live_after)"},
      {"foreign_keyframes", &C::foreign_keyframes, "other vehicles' keyframes searched and held"},
      {"foreign_loops", &C::foreign_loops, "global loops closed by other vehicles' keyframes"},
      {"feature_cache_hits", &C::feature_cache_hits, "paged keyframes' features found in the cache"},
      {"feature_cache_misses", &C::feature_cache_misses, "paged keyframes' features read through keyframe_features"},
      {"feature_cache_mb", &C::feature_cache_mb, "the feature cache's size, MiB"},
      {"feature_read_failures", &C::feature_read_failures,
       "candidates skipped: their features could not be read from the back-end's store", kWarn},
      {"ms_per_keyframe_mean", &C::ms_per_keyframe_mean, "mean time per keyframe received, ms"},
      {"ms_per_keyframe_max", &C::ms_per_keyframe_max, "longest time of a keyframe, ms"},
  };
  return table;
}

void setDetectorCounters(const core::LoopDetector& detector, LoopDetectorCounters* c) {
  c->keyframes_stored = static_cast<long>(detector.size());
  c->local_candidates = detector.stats().local_candidates;
  c->global_candidates = detector.stats().global_candidates;
  c->feature_read_failures = detector.stats().feature_read_failures;
  if (const core::FeatureCache* cache = detector.featureCache()) {
    c->feature_cache_hits = cache->stats().hits;
    c->feature_cache_misses = cache->stats().misses;
    c->feature_cache_mb = static_cast<double>(cache->bytes()) / (1024.0 * 1024.0);
  }
}

}  // namespace ros_diagnostics
}  // namespace uw_multislam
