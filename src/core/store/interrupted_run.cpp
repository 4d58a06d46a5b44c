#include "uw_multislam/core/store/interrupted_run.h"

#include <cmath>
#include <map>

namespace uw_multislam {
namespace core {

bool keyframesAreFramesOf(const std::vector<int>& frame_indexes, const std::vector<double>& stamps,
                          const std::vector<FrameRecord>& frames) {
  if (frame_indexes.empty() || frame_indexes.size() != stamps.size()) return false;
  std::map<int, double> stamp_of;
  for (const FrameRecord& f : frames) stamp_of[f.index] = f.stamp_s;
  for (std::size_t k = 0; k < frame_indexes.size(); ++k) {
    const auto it = stamp_of.find(frame_indexes[k]);
    if (it == stamp_of.end() || std::abs(it->second - stamps[k]) >= 1e-6) return false;
  }
  return true;
}

std::vector<InterruptedRun> findInterruptedRuns(const SessionStore& store, const std::vector<FrameRecord>& frames) {
  struct Seen {
    StoredSession s;
    int id = -1;
    std::vector<int> indexes;
    std::vector<double> stamps;
    bool ours = false;
  };
  std::vector<Seen> seen;
  for (const StoredSession& s : store.sessions()) {
    // A row without keyframes (a crash before its first) is never restored. A session's id is its store id.
    if (s.keyframes == 0) continue;
    Seen x{s, static_cast<int>(s.id), {}, {}, false};
    for (const StoredKeyframe& k : store.keyframes(s.id, false)) {
      x.indexes.push_back(k.frame_index);
      x.stamps.push_back(k.stamp_s);
    }
    x.ours = keyframesAreFramesOf(x.indexes, x.stamps, frames);
    seen.push_back(std::move(x));
  }
  std::vector<InterruptedRun> runs;
  for (std::size_t i = 0; i < seen.size(); ++i) {
    if (!seen[i].ours || seen[i].s.state != StoredSessionState::kRecording) continue;
    InterruptedRun run;
    run.name = seen[i].s.name;
    run.last_stamp_s = seen[i].stamps.back();
    std::size_t first = i;
    while (first > 0 && seen[first - 1].ours && seen[first - 1].s.state == StoredSessionState::kFinished &&
           seen[first - 1].indexes.back() < seen[first].indexes.front())
      --first;
    for (std::size_t j = first; j <= i; ++j) {
      run.store_ids.push_back(seen[j].s.id);
      run.ids.push_back(seen[j].id);
      run.keyframes += static_cast<int>(seen[j].indexes.size());
    }
    runs.push_back(std::move(run));
  }
  return runs;
}

void resolveInterruptedRun(SessionStore* store, const InterruptedRun& run, InterruptedChoice choice) {
  if (choice == InterruptedChoice::kDiscard) {
    // The audit trail: a deletion by the tool, in the deletion's transaction.
    std::string ids;
    for (int id : run.ids) ids += (ids.empty() ? "" : ",") + std::to_string(id);
    const HistoryEntry entry{0,
                             utcTimestamp(),
                             "delete",
                             "tool",
                             ids,
                             "",
                             "offline_slam --interrupted discard: the interrupted run of '" + run.name + "' deleted (" +
                                 std::to_string(run.store_ids.size()) + " sessions, " + std::to_string(run.keyframes) +
                                 " keyframes, their loops and their places in the maps)"};
    store->deleteSessions(run.store_ids, &entry);
  } else {
    store->endSession(run.store_ids.back(), run.last_stamp_s);
  }
}

}  // namespace core
}  // namespace uw_multislam
