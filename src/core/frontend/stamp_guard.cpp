#include "uw_multislam/core/frontend/stamp_guard.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <vector>

namespace uw_multislam {
namespace core {

std::string StampGuardOptions::validate() const {
  std::ostringstream os;
  if (!(std::isfinite(reorder_tolerance_s) && reorder_tolerance_s >= 0)) {
    os << "reorder_tolerance_s = " << reorder_tolerance_s << ": must be >= 0";
  } else if (!(std::isfinite(session_gap_s) && session_gap_s >= 0)) {
    os << "session_gap_s = " << session_gap_s << ": must be >= 0 (0 = off)";
  } else if (!(std::isfinite(gap_periods) && gap_periods >= 1)) {
    os << "session_gap_periods = " << gap_periods << ": must be >= 1";
  }
  return os.str();
}

std::string stampClassName(StampClass c) {
  switch (c) {
    case StampClass::kFirst:
      return "first";
    case StampClass::kNext:
      return "next";
    case StampClass::kDuplicate:
      return "duplicate";
    case StampClass::kOutOfOrder:
      return "out_of_order";
    case StampClass::kJumpBack:
      return "jump_back";
    case StampClass::kJumpForward:
      return "jump_forward";
  }
  return "?";
}

StampGuard::StampGuard(const StampGuardOptions& options) : options_(options) {
  const std::string bad = options_.validate();
  if (!bad.empty()) throw std::invalid_argument("stamp guard: " + bad);
}

StampClass StampGuard::classify(double stamp_s) const {
  if (!std::isfinite(stamp_s)) return StampClass::kOutOfOrder;
  if (!have_last_) return StampClass::kFirst;
  if (stamp_s == last_) return StampClass::kDuplicate;
  if (stamp_s < last_)
    return last_ - stamp_s <= options_.reorder_tolerance_s ? StampClass::kOutOfOrder : StampClass::kJumpBack;
  if (stamp_s - last_ > gapThreshold()) return StampClass::kJumpForward;
  return StampClass::kNext;
}

std::optional<double> StampGuard::period() const {
  if (intervals_.size() < kMinIntervals) return std::nullopt;
  std::vector<double> sorted(intervals_.begin(), intervals_.end());
  const auto mid = sorted.begin() + static_cast<std::ptrdiff_t>(sorted.size() / 2);
  std::nth_element(sorted.begin(), mid, sorted.end());
  if (sorted.size() % 2 == 1) return *mid;
  return 0.5 * (*mid + *std::max_element(sorted.begin(), mid));
}

double StampGuard::gapThreshold() const {
  if (options_.session_gap_s <= 0) return std::numeric_limits<double>::infinity();
  const std::optional<double> p = period();
  if (!p) return options_.gap_periods * options_.session_gap_s;
  return std::max(options_.session_gap_s, options_.gap_periods * *p);
}

void StampGuard::advance(double stamp_s, StampClass c) {
  // The camera's rhythm: the intervals of a running stream, never a jump (nor the first stamp).
  if (c == StampClass::kNext) {
    intervals_.push_back(stamp_s - last_);
    if (intervals_.size() > kPeriodWindow) intervals_.pop_front();
  }
  have_last_ = true;
  last_ = stamp_s;
}

StampClass StampGuard::accept(double stamp_s) {
  const StampClass here = classify(stamp_s);
  if (skips(here)) return here;
  StampClass c = here;
  if (startsSession(here)) {
    last_jump_s_ = stamp_s - last_;
  } else if (startsSession(held_)) {
    c = held_;  // the jump happened among the frames passed over since the last accepted one
  }
  held_ = StampClass::kNext;
  advance(stamp_s, here);
  return c;
}

void StampGuard::passOver(double stamp_s) {
  const StampClass c = classify(stamp_s);
  if (skips(c)) return;
  if (startsSession(c)) {
    last_jump_s_ = stamp_s - last_;
    if (!startsSession(held_)) held_ = c;  // the first jump decides the class
  }
  advance(stamp_s, c);
}

}  // namespace core
}  // namespace uw_multislam
