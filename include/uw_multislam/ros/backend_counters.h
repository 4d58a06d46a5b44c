// The back-end nodelet's counters (/diagnostics status "<node>: backend", and its periodic and
// shutdown log lines): one field each, named once in backendCounterTable() (and, with fleet/vehicle
// set, fleetCounterTable()) with its help text; doc/diagnostics.md documents them and
// test/ros/test_diagnostics.cpp checks it against the tables.
#pragma once

#include "uw_multislam/core/session/session_worker.h"
#include "uw_multislam/ros/diagnostics.h"

namespace uw_multislam {
namespace ros_frames {
struct FrameStats;
}
namespace ros_mosaic {
struct MosaicStats;
}
namespace ros_fleet {
struct HashExchangeStats;
struct PeerStats;
}  // namespace ros_fleet
namespace ros_diagnostics {

struct BackendCounters {
  // The worker's queue and the messages it took.
  long messages_received = 0, keyframes_received = 0, loops_received = 0, loops_waiting = 0;
  long loops_dropped_waiting = 0, dropped_queue_full = 0, queue_length = 0, bad_messages = 0;
  // map -> odom.
  long map_to_odom_published = 0, odom_lookup_failures = 0;
  double map_to_odom_rate_hz = 0.0;
  // Operator services, the stored keyframes' handover, relocalisation, the live mosaic.
  long sessions_unloaded = 0, sessions_deleted = 0;
  long handover_subscribers = 0, handover_keyframes_total = 0, handover_keyframes_sent = 0;
  double handover_s = 0.0;
  long relocalised_map = -1, relocalised_loops = 0, relocalised_poses_published = 0;
  long mosaic_published = 0, mosaic_keyframes_drawn = 0, mosaic_keyframes_missing = 0;
  double mosaic_draw_ms = 0.0, mosaic_resolution_m = 0.0, mosaic_images_kB = 0.0;
  // The session manager and its back-end (setManagerCounters).
  long keyframes_stale = 0, keyframes_refused = 0, keyframes_unopened = 0, keyframe_gaps = 0, keyframe_jumps = 0,
       nav_placements = 0, loops_refused = 0, store_failures = 0;
  long sessions = 0, sessions_unloaded_now = 0, maps = 0, joins = 0, splits = 0;
  long loops_refused_at_join = 0, joins_refused = 0, loops_gated = 0, loops_switched_off = 0, loops_readmitted = 0;
  long optimisations = 0, optimisations_discarded = 0;
  double optimise_ms_max = 0.0;
  // The NavSatFix input (ros/fix_input.h): fixes used as position priors, waiting, refused by reason.
  long fixes_used = 0, fixes_waiting = 0;
  long fixes_refused_no_fix = 0, fixes_refused_not_finite = 0, fixes_refused_unknown_covariance = 0,
       fixes_refused_bad_variance = 0, fixes_refused_no_datum = 0, fixes_refused_no_keyframe = 0,
       fixes_refused_other_map = 0, fixes_refused_map_origin = 0, fixes_refused_keyframe_has_fix = 0,
       fixes_refused_outlier = 0, fixes_refused_no_lever_arm = 0;
};

/// The hash exchange and the feature requests between vehicles (only with fleet/vehicle set).
struct FleetCounters {
  long hashes_sent = 0, hash_bytes_sent = 0, hashes_received = 0, hash_bytes_received = 0;
  long refused = 0, sessions_ended = 0;
  long features_requested = 0, feature_bytes_received = 0, feature_failures = 0, feature_timeouts = 0;
};

const CounterTable<BackendCounters>& backendCounterTable();
const CounterTable<FleetCounters>& fleetCounterTable();

/// The fleet counters as fleetCounterTable() names them (a function of its own: GCC 12 warns, wrongly, that a
/// local FleetCounters is used uninitialised when the table's std::visit is inlined into the caller).
std::vector<Counter> fleetCounters(const FleetCounters& c);

/// The fleet rows from the hash exchange (what crossed the link, per direction) and the feature
/// requests forwarded to the other vehicles.
std::vector<Counter> fleetCounters(const ros_fleet::HashExchangeStats& x, const ros_fleet::PeerStats& p);

/// The session manager's and its back-end's counters into `c` (call under the worker's lock).
void setManagerCounters(const core::SessionQueries& manager, BackendCounters* c);

/// The worker's queue into `c`, with the keyframes and loops the nodelet refused before they reached
/// it (unreadable messages); and the newest handover of the stored keyframes to a loop detector
/// (reloaded_keyframes): its progress while it runs (sent of total), then how long it took.
void setWorkerCounters(const core::SessionWorkerStats& w, const core::HandoverStats& h, long bad_keyframes,
                       long bad_loops, BackendCounters* c);

/// map -> odom as the frame publisher counts it.
void setFrameCounters(const ros_frames::FrameStats& f, BackendCounters* c);

/// The active session's relocalisation in a stored map (relocalised_*).
void setRelocalisationCounters(const core::RelocalisationTracker::State& r, BackendCounters* c);

/// The back-end status's values beside its counters (doc/diagnostics.md): `optimizer`, `store` (its
/// path, or none), `mode` (mapping or localisation), `relocalised` ("session S in map M", or "no").
/// Call under the worker's lock.
void addBackendValues(diagnostic_updater::DiagnosticStatusWrapper& stat, const core::SessionQueries& m,
                      const std::string& optimizer, const std::string& store_path,
                      const core::RelocalisationTracker::State& r);

/// The live mosaic's last drawing and the thumbnails it keeps.
void setMosaicCounters(const ros_mosaic::MosaicStats& s, BackendCounters* c);

}  // namespace ros_diagnostics
}  // namespace uw_multislam
