#include "uw_multislam/ros/backend_counters.h"

#include "uw_multislam/core/session/session_queries.h"
#include "uw_multislam/ros/fleet_hash_exchange.h"
#include "uw_multislam/ros/fleet_peer_client.h"
#include "uw_multislam/ros/frame_publisher.h"
#include "uw_multislam/ros/live_mosaic_publisher.h"

namespace uw_multislam {
namespace ros_diagnostics {

const CounterTable<BackendCounters>& backendCounterTable() {
  using C = BackendCounters;
  constexpr bool kWarn = true;  // a drop, a refusal or a failure: the status WARNs while it grows
  static const CounterTable<C> table = {
      {"messages_received", &C::messages_received, "messages taken from the subscriptions onto the worker's queue"},
      {"keyframes_received", &C::keyframes_received, "keyframes received"},
      {"loops_received", &C::loops_received, "loops received"},
      {"loops_waiting", &C::loops_waiting, "loops waiting for their keyframes now"},
      {"loops_dropped_waiting", &C::loops_dropped_waiting,
       "loops dropped while waiting for their keyframes (the wait is bounded)", kWarn},
      {"dropped_queue_full", &C::dropped_queue_full, "messages the worker's queue dropped when full", kWarn},
      {"queue_length", &C::queue_length, "messages waiting in the worker's queue"},
      {"bad_messages", &C::bad_messages, "messages refused as unreadable", kWarn},
      {"map_to_odom_published", &C::map_to_odom_published, "map -> odom transforms published"},
      {"map_to_odom_rate_hz", &C::map_to_odom_rate_hz, "their rate, Hz"},
      {"odom_lookup_failures", &C::odom_lookup_failures,
       "odom -> base_link lookups that failed (the vehicle's own odometry)", kWarn},
      {"sessions_unloaded", &C::sessions_unloaded, "sessions unloaded (unload_session)"},
      {"handover_subscribers", &C::handover_subscribers, "loop detectors the stored keyframes were handed over to"},
      {"handover_keyframes_total", &C::handover_keyframes_total, "stored keyframes of the newest handover"},
      {"handover_keyframes_sent", &C::handover_keyframes_sent, "of those, sent so far"},
      {"handover_s", &C::handover_s, "how long the newest handover took, s"},
      {"sessions_deleted", &C::sessions_deleted, "sessions deleted (delete_session)"},
      {"relocalised_map", &C::relocalised_map, "the stored map the active session is relocalised in (-1: none)"},
      {"relocalised_loops", &C::relocalised_loops, "loops to it"},
      {"relocalised_poses_published", &C::relocalised_poses_published, "poses published on relocalised_pose"},
      {"mosaic_published", &C::mosaic_published, "live mosaics published"},
      {"mosaic_keyframes_drawn", &C::mosaic_keyframes_drawn, "keyframes drawn in the last one"},
      {"mosaic_keyframes_missing", &C::mosaic_keyframes_missing, "keyframes without a thumbnail in the last one"},
      {"mosaic_draw_ms", &C::mosaic_draw_ms, "time to draw the last one, ms"},
      {"mosaic_resolution_m", &C::mosaic_resolution_m, "its resolution, m/px"},
      {"mosaic_images_kB", &C::mosaic_images_kB, "thumbnails kept for the mosaic, kB"},
      {"keyframes_stale", &C::keyframes_stale, "keyframes of a session no longer recording (e.g. after finish_session)",
       kWarn},
      {"keyframes_refused", &C::keyframes_refused,
       "keyframes refused: an id more than ~max_keyframe_gap past the last, or a session id past 1,000,000", kWarn},
      {"keyframes_unopened", &C::keyframes_unopened,
       "keyframes of a session the back-end did not open (past the next id, or another vehicle's): refused", kWarn},
      {"keyframe_gaps", &C::keyframe_gaps, "gaps in the keyframe ids, bridged", kWarn},
      {"keyframe_jumps", &C::keyframe_jumps,
       "jumps in the keyframe ids past ~max_keyframe_gap that the next keyframe continued: a new session from there",
       kWarn},
      {"nav_placements", &C::nav_placements, "sessions placed in their predecessor's map by the nav"},
      {"loops_refused", &C::loops_refused, "loops refused by the session manager", kWarn},
      {"store_failures", &C::store_failures, "session store writes that failed", kWarn},
      {"sessions", &C::sessions, "sessions known"},
      {"sessions_unloaded_now", &C::sessions_unloaded_now,
       "of those, unloaded now (in the store only, their keyframes not in memory)"},
      {"maps", &C::maps, "maps"},
      {"joins", &C::joins, "joins"},
      {"splits", &C::splits, "splits"},
      {"loops_refused_at_join", &C::loops_refused_at_join,
       "every loop the back-end refused: at a join, by the entry gate or switched off"},
      {"joins_refused", &C::joins_refused, "joins refused"},
      {"loops_gated", &C::loops_gated, "loops refused by the entry gate inside a map"},
      {"loops_switched_off", &C::loops_switched_off, "loops switched off by the residual gate after a solve"},
      {"loops_readmitted", &C::loops_readmitted, "refused loops taken back after a solve"},
      {"optimisations", &C::optimisations, "optimisations"},
      {"optimisations_discarded", &C::optimisations_discarded,
       "results dropped because a service changed their map while they were solved (solved again)"},
      {"optimise_ms_max", &C::optimise_ms_max, "longest optimisation, ms"},
      {"fixes_used", &C::fixes_used, "fixes used as position priors (~fix/topic)"},
      {"fixes_waiting", &C::fixes_waiting, "fixes newer than every keyframe, waiting for the next one now"},
      {"fixes_refused_no_fix", &C::fixes_refused_no_fix, "fixes refused: status NO_FIX", kWarn},
      {"fixes_refused_not_finite", &C::fixes_refused_not_finite,
       "fixes refused: latitude or longitude not a number or out of range", kWarn},
      {"fixes_refused_unknown_covariance", &C::fixes_refused_unknown_covariance,
       "fixes refused: covariance type UNKNOWN and no ~fix/default_sigma_m", kWarn},
      {"fixes_refused_bad_variance", &C::fixes_refused_bad_variance,
       "fixes refused: an east/north variance not finite or not positive, or not positive definite", kWarn},
      {"fixes_refused_no_datum", &C::fixes_refused_no_datum, "fixes refused: no datum yet (~datum/* or set_datum)",
       kWarn},
      {"fixes_refused_no_keyframe", &C::fixes_refused_no_keyframe,
       "fixes refused: no keyframe within ~fix/max_dt_s (or dropped from a full waiting list)", kWarn},
      {"fixes_refused_other_map", &C::fixes_refused_other_map,
       "fixes refused: their keyframe is not in the map the datum places (the active session's)", kWarn},
      {"fixes_refused_map_origin", &C::fixes_refused_map_origin,
       "fixes refused: their keyframe is its map's origin (the map's frame, fixed)", kWarn},
      {"fixes_refused_keyframe_has_fix", &C::fixes_refused_keyframe_has_fix,
       "fixes refused: their keyframe has a fix already (one per keyframe)"},
      {"fixes_refused_outlier", &C::fixes_refused_outlier,
       "fixes refused: beyond ~fix/gate_chi2 from their keyframe (a jump, multipath)", kWarn},
      {"fixes_refused_no_lever_arm", &C::fixes_refused_no_lever_arm,
       "fixes refused: no static base_link -> their frame in tf (or not on the vehicle)", kWarn},
  };
  return table;
}

const CounterTable<FleetCounters>& fleetCounterTable() {
  using C = FleetCounters;
  constexpr bool kWarn = true;
  static const CounterTable<C> table = {
      {"fleet_hashes_sent", &C::hashes_sent, "keyframe hashes sent to the other vehicles"},
      {"fleet_hash_bytes_sent", &C::hash_bytes_sent, "their bytes"},
      {"fleet_hashes_received", &C::hashes_received, "other vehicles' hashes received"},
      {"fleet_hash_bytes_received", &C::hash_bytes_received, "their bytes"},
      {"fleet_refused", &C::refused, "other vehicles' messages refused", kWarn},
      {"fleet_sessions_ended", &C::sessions_ended, "other vehicles' sessions ended"},
      {"fleet_features_requested", &C::features_requested, "keyframe features asked of other vehicles"},
      {"fleet_feature_bytes_received", &C::feature_bytes_received, "their bytes"},
      {"fleet_feature_failures", &C::feature_failures, "such requests that failed", kWarn},
      {"fleet_feature_timeouts", &C::feature_timeouts, "such requests that timed out (~fleet/peer_timeout_s)", kWarn},
  };
  return table;
}

std::vector<Counter> fleetCounters(const FleetCounters& c) { return fleetCounterTable().counters(c); }

std::vector<Counter> fleetCounters(const ros_fleet::HashExchangeStats& x, const ros_fleet::PeerStats& p) {
  FleetCounters c;
  c.hashes_sent = x.hashes_sent, c.hash_bytes_sent = x.hash_bytes_sent, c.hashes_received = x.hashes_received;
  c.hash_bytes_received = x.hash_bytes_received, c.refused = x.refused, c.sessions_ended = x.sessions_ended;
  c.features_requested = p.requested, c.feature_bytes_received = p.bytes_received;
  c.feature_failures = p.failures, c.feature_timeouts = p.timeouts;
  return fleetCounters(c);
}

void setWorkerCounters(const core::SessionWorkerStats& w, const core::HandoverStats& h, long bad_keyframes,
                       long bad_loops, BackendCounters* c) {
  c->keyframes_received = w.keyframes + bad_keyframes, c->loops_received = w.loops + bad_loops;
  c->loops_waiting = static_cast<long>(w.waiting), c->loops_dropped_waiting = w.waiting_dropped;
  c->dropped_queue_full = w.dropped_queue_full, c->queue_length = static_cast<long>(w.queued);
  c->bad_messages = w.skipped + bad_keyframes + bad_loops;
  c->handover_subscribers = h.subscribers, c->handover_keyframes_total = h.total;
  c->handover_keyframes_sent = h.sent, c->handover_s = h.seconds;
}

void setFrameCounters(const ros_frames::FrameStats& f, BackendCounters* c) {
  c->map_to_odom_published = f.map_to_odom_published, c->map_to_odom_rate_hz = f.map_to_odom_rate_hz;
  c->odom_lookup_failures = f.odom_lookup_failures;
}

void setRelocalisationCounters(const core::RelocalisationTracker::State& r, BackendCounters* c) {
  c->relocalised_map = r.map, c->relocalised_loops = r.loops, c->relocalised_poses_published = r.published;
}

void addBackendValues(diagnostic_updater::DiagnosticStatusWrapper& stat, const core::SessionQueries& m,
                      const std::string& optimizer, const std::string& store_path,
                      const core::RelocalisationTracker::State& r) {
  stat.add("optimizer", optimizer);
  stat.add("store", m.hasStore() ? store_path : std::string("none"));
  stat.add("mode", m.localising() ? "localisation" : "mapping");
  stat.add("relocalised", r.map >= 0 ? "session " + std::to_string(r.session) + " in map " + std::to_string(r.map)
                                     : std::string("no"));
}

void setMosaicCounters(const ros_mosaic::MosaicStats& s, BackendCounters* c) {
  c->mosaic_published = s.published, c->mosaic_keyframes_drawn = s.drawn, c->mosaic_keyframes_missing = s.missing;
  c->mosaic_draw_ms = s.ms, c->mosaic_resolution_m = s.resolution_m, c->mosaic_images_kB = s.images_kB;
}

void setManagerCounters(const core::SessionQueries& manager, BackendCounters* c) {
  const core::SessionManagerStats& m = manager.stats();
  const core::BackendStats& b = manager.backendStats();
  c->keyframes_stale = m.keyframes_stale, c->keyframes_refused = m.keyframes_refused;
  c->keyframes_unopened = m.keyframes_unopened;
  c->keyframe_gaps = m.keyframe_gaps, c->keyframe_jumps = m.keyframe_jumps, c->nav_placements = m.nav_placements,
  c->loops_refused = m.loops_refused, c->store_failures = m.store_failures;
  c->sessions = static_cast<long>(manager.sessionIds().size());
  c->sessions_unloaded_now = 0;
  for (const core::SessionSummary& s : manager.list())
    c->sessions_unloaded_now += s.state == core::SessionState::kUnloaded;
  c->maps = static_cast<long>(manager.mapIds().size());
  c->joins = b.joins, c->splits = b.splits, c->loops_refused_at_join = b.loops_refused;
  c->joins_refused = b.joins_refused, c->loops_gated = b.loops_gated, c->loops_switched_off = b.loops_switched_off;
  c->loops_readmitted = b.loops_readmitted, c->optimisations = b.optimisations;
  c->optimisations_discarded = b.optimisations_discarded, c->optimise_ms_max = b.optimise_ms_max;
}

}  // namespace ros_diagnostics
}  // namespace uw_multislam
