#include "uw_multislam/core/common/stage_timer.h"

#include <algorithm>

namespace uw_multislam {
namespace core {

void StageTimes::add(const std::string& stage, double ms) {
  auto it = std::find_if(stats_.begin(), stats_.end(), [&](const StageStats& s) { return s.stage == stage; });
  if (it == stats_.end()) {
    stats_.push_back(StageStats{stage});
    it = stats_.end() - 1;
  }
  ++it->calls;
  it->total_ms += ms;
  it->max_ms = std::max(it->max_ms, ms);
}

void StageTimes::merge(const StageTimes& other) {
  for (const auto& s : other.stats_) {
    auto it = std::find_if(stats_.begin(), stats_.end(), [&](const StageStats& x) { return x.stage == s.stage; });
    if (it == stats_.end()) {
      stats_.push_back(s);
    } else {
      it->calls += s.calls;
      it->total_ms += s.total_ms;
      it->max_ms = std::max(it->max_ms, s.max_ms);
    }
  }
}

StageStats StageTimes::get(const std::string& stage) const {
  for (const auto& s : stats_) {
    if (s.stage == stage) return s;
  }
  return StageStats{stage};
}

}  // namespace core
}  // namespace uw_multislam
