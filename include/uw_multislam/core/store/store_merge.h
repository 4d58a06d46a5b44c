// Fleet merge: session stores of several vehicles or dives into one, then the
// global loops between them and the joins they support.
//
// 1. Copy. Every session of every input with at least one keyframe is copied in input order (its
//    keyframes with features, hash and image, its odometry motions and their sources, its loops,
//    its maps and split pairs), renumbered by the new store, with its provenance (source file,
//    source session and name, vehicle, dive: SessionStore::provenance). Inputs are opened
//    read-only and never written. The output is written to a temporary file beside it and renamed
//    only when complete (and its loop search done): a failure leaves no OUT, and OUT is never
//    overwritten.
// 2. Refusals, before anything is written: hash settings (mode, seed, n, the projection vectors)
//    that differ between inputs (the reason names both), a session still `recording` (an
//    interrupted run: finish or discard it first), the same file twice, OUT existing.
// 3. Loops (core/session/stored_loops.h, one group per input). The sessions of input i search the
//    sessions of inputs 0..i-1 for global loops, as if
//    they had been recorded after them in one run: each keyframe's stored hash is queried
//    (LoopDetector::globalCandidates, best_k candidates among the earlier inputs' sessions only),
//    each candidate verified by RANSAC on the stored features, and every accepted loop handed to
//    the SessionManager in keyframe order. The manager's join policy (backend.join_policy,
//    count or consistent) decides the joins, as it does live; then every map is optimised and the
//    maps are saved. Loops inside one input were found when it was recorded and are copied.
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "uw_multislam/core/session/slam_config.h"

namespace uw_multislam {
namespace core {

struct MergeInput {
  std::string path;
  std::string vehicle;  // empty: the file's stem
  std::string dive;     // empty: each session's own name
};

struct MergeReport {
  int inputs = 0, sessions = 0, keyframes = 0, copied_loops = 0, skipped_empty_sessions = 0;
  int renamed_sessions = 0;
  int queries = 0, candidates = 0, loops_found = 0, loops_accepted = 0, loops_refused = 0;
  int joins = 0, maps = 0;
};

/// Merges `inputs` into the new store `out` (see the file comment). The hash settings of the
/// configuration are replaced by the inputs' (they must agree); the rest of `config` (loop
/// verification, back-end, join policy) is used for the loop search. `search_loops` false: copy
/// only. Throws std::invalid_argument (bad arguments, settings that differ, a recording session)
/// or StoreError (an unreadable input, a failed write); then neither OUT nor a temporary file is
/// left.
MergeReport mergeStores(const std::string& out, const std::vector<MergeInput>& inputs, SlamConfig config,
                        bool search_loops = true, const std::function<void(const std::string&)>& log = {});

}  // namespace core
}  // namespace uw_multislam
