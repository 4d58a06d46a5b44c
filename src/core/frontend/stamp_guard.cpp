#include "uw_multislam/core/frontend/stamp_guard.h"

#include <cmath>
#include <sstream>
#include <stdexcept>

namespace uw_multislam {
namespace core {

std::string StampGuardOptions::validate() const {
  std::ostringstream os;
  if (!(std::isfinite(reorder_tolerance_s) && reorder_tolerance_s >= 0)) {
    os << "reorder_tolerance_s = " << reorder_tolerance_s << ": must be >= 0";
  } else if (!(std::isfinite(session_gap_s) && session_gap_s >= 0)) {
    os << "session_gap_s = " << session_gap_s << ": must be >= 0 (0 = off)";
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
  if (options_.session_gap_s > 0 && stamp_s - last_ > options_.session_gap_s) return StampClass::kJumpForward;
  return StampClass::kNext;
}

StampClass StampGuard::accept(double stamp_s) {
  StampClass c = classify(stamp_s);
  if (skips(c)) return c;
  if (startsSession(c)) {
    last_jump_s_ = stamp_s - last_;
  } else if (startsSession(held_)) {
    c = held_;  // the jump happened among the frames passed over since the last accepted one
  }
  held_ = StampClass::kNext;
  have_last_ = true;
  last_ = stamp_s;
  return c;
}

void StampGuard::passOver(double stamp_s) {
  const StampClass c = classify(stamp_s);
  if (skips(c)) return;
  if (startsSession(c)) {
    last_jump_s_ = stamp_s - last_;
    if (!startsSession(held_)) held_ = c;  // the first jump decides the class
  }
  have_last_ = true;
  last_ = stamp_s;
}

}  // namespace core
}  // namespace uw_multislam
