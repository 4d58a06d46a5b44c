#include "uw_multislam/ros/diagnostics.h"

#include <diagnostic_msgs/DiagnosticStatus.h>

#include <cmath>
#include <cstdio>
#include <sstream>

namespace uw_multislam {
namespace ros_diagnostics {

std::string formatValue(double v) {
  char buf[64];
  if (std::isfinite(v) && v == std::floor(v) && std::fabs(v) < 1e15) {
    std::snprintf(buf, sizeof(buf), "%.0f", v);
  } else {
    std::snprintf(buf, sizeof(buf), "%.3f", v);
  }
  return buf;
}

void CounterStatus::fill(diagnostic_updater::DiagnosticStatusWrapper& stat, const std::vector<Counter>& counters,
                         double now_s, const std::string& problem, const std::string& error) {
  std::ostringstream grown;
  for (const Counter& c : counters) {
    stat.add(c.key, formatValue(c.value));
    if (!c.warn_on_growth) continue;
    auto found = watched_.find(c.key);
    if (found == watched_.end()) {
      Watched w;
      w.last_value = c.value;
      if (c.value > 0) {  // already non-zero at the first report: it grew since start-up
        w.grown_at_s = now_s;
        w.growth = c.value;
      }
      found = watched_.emplace(c.key, w).first;
    }
    Watched& w = found->second;
    if (c.value > w.last_value) {
      if (now_s - w.grown_at_s > warn_hold_s_) w.growth = 0.0;
      w.growth += c.value - w.last_value;
      w.grown_at_s = now_s;
    }
    w.last_value = c.value;
    if (now_s - w.grown_at_s <= warn_hold_s_) {
      grown << (grown.tellp() > 0 ? ", " : "") << c.key << " +" << formatValue(w.growth);
    }
  }
  using diagnostic_msgs::DiagnosticStatus;
  if (!error.empty()) {
    stat.summary(DiagnosticStatus::ERROR, error);
  } else if (!problem.empty()) {
    stat.summary(DiagnosticStatus::WARN, problem);
  } else if (grown.tellp() > 0) {
    std::ostringstream os;
    os << grown.str() << " in the last " << formatValue(warn_hold_s_) << " s";
    stat.summary(DiagnosticStatus::WARN, os.str());
  } else {
    stat.summary(DiagnosticStatus::OK, "OK");
  }
}

std::string countersLine(const std::string& prefix, const std::vector<Counter>& counters) {
  std::string line = prefix;
  for (const Counter& c : counters) line += " " + c.key + " " + formatValue(c.value);
  return line;
}

}  // namespace ros_diagnostics
}  // namespace uw_multislam
