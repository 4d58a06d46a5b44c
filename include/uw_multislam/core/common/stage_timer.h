// Wall-clock time per pipeline stage (offline_slam's timing.csv, the benchmarks, diagnostics).
#pragma once

#include <chrono>
#include <string>
#include <vector>

namespace uw_multislam {
namespace core {

struct StageStats {
  std::string stage;
  long calls = 0;
  double total_ms = 0.0;
  double max_ms = 0.0;
  double meanMs() const { return calls ? total_ms / calls : 0.0; }
};

/// Stages in the order they were first seen.
class StageTimes {
 public:
  void add(const std::string& stage, double ms);
  void merge(const StageTimes& other);
  const std::vector<StageStats>& stats() const { return stats_; }
  /// Zero-call stats when the stage was never timed.
  StageStats get(const std::string& stage) const;

 private:
  std::vector<StageStats> stats_;
};

/// Times its own lifetime into a StageTimes (which may be null: then it does nothing).
class ScopedStage {
 public:
  ScopedStage(StageTimes* times, std::string stage)
      : times_(times), stage_(std::move(stage)), start_(std::chrono::steady_clock::now()) {}
  ~ScopedStage() {
    if (times_) {
      times_->add(stage_, std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start_).count());
    }
  }
  ScopedStage(const ScopedStage&) = delete;
  ScopedStage& operator=(const ScopedStage&) = delete;

 private:
  StageTimes* times_;
  std::string stage_;
  std::chrono::steady_clock::time_point start_;
};

}  // namespace core
}  // namespace uw_multislam
