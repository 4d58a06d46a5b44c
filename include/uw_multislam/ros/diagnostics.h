// Counters -> diagnostic_msgs status for the nodelets' diagnostic_updater tasks (published on
// /diagnostics). One helper so that every nodelet reports the same way:
//
//   ros_diagnostics::CounterStatus status(10.0);   // WARN held 10 s after a watched counter grew
//   updater.add("odometry", [&](diagnostic_updater::DiagnosticStatusWrapper& s) {
//     status.fill(s, {{"frames", n}, {"dropped", d, true}, ...}, ros::WallTime::now().toSec(), problem);
//   });
//
// Level: ERROR when `error` is non-empty, else WARN when `problem` is non-empty or a counter
// marked warn_on_growth grew within warn_hold_s (the message names which and by how much), else
// OK. Every counter becomes one key/value pair, in the order given (integers without decimals).
// Not thread-safe: call fill() from one thread (the updater's). Tested in
// test/ros/test_diagnostics.cpp.
#pragma once

#include <diagnostic_updater/DiagnosticStatusWrapper.h>

#include <map>
#include <string>
#include <vector>

namespace uw_multislam {
namespace ros_diagnostics {

struct Counter {
  std::string key;
  double value = 0.0;
  bool warn_on_growth = false;  // drops, skips: WARN while it grows
};

class CounterStatus {
 public:
  explicit CounterStatus(double warn_hold_s = 10.0) : warn_hold_s_(warn_hold_s) {}

  void fill(diagnostic_updater::DiagnosticStatusWrapper& stat, const std::vector<Counter>& counters, double now_s,
            const std::string& problem = "", const std::string& error = "");

 private:
  struct Watched {
    double last_value = 0.0;
    double grown_at_s = -1e300;
    double growth = 0.0;  // growth over the hold period, for the message
  };
  double warn_hold_s_;
  std::map<std::string, Watched> watched_;
};

/// Formats a value as the key/value pairs show it: integers without decimals, else 3 decimals.
std::string formatValue(double v);
/// The counters as one log line: "<prefix> key value key value ...".
std::string countersLine(const std::string& prefix, const std::vector<Counter>& counters);

}  // namespace ros_diagnostics
}  // namespace uw_multislam
