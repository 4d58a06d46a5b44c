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
// Not thread-safe: call fill() from one thread (the updater's).
//
// Each nodelet writes its counters once, as a struct of `long` / `double` fields and a
// CounterTable binding each field to its key, its help text and whether it WARNs while it grows
// (ros/odometry_counters.h, ros/loop_detector_counters.h); the /diagnostics status and the
// periodic and shutdown log lines are made from the table, and a test checks doc/diagnostics.md
// against the tables' specs(). Tested in test/ros/test_diagnostics.cpp.
#pragma once

#include <diagnostic_updater/DiagnosticStatusWrapper.h>

#include <initializer_list>
#include <map>
#include <set>
#include <stdexcept>
#include <string>
#include <variant>
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

/// One counter as doc/diagnostics.md documents it.
struct CounterSpec {
  std::string key;
  std::string help;  // what it counts: the documentation's "meaning", word for word
  bool warn_on_growth = false;
};

/// The counters of a struct S, each field named once with its spec.
template <class S>
class CounterTable {
 public:
  struct Field {
    const char* key;
    std::variant<long S::*, double S::*> member;
    const char* help;
    bool warn_on_growth = false;
  };
  /// Throws std::logic_error for a key given twice or a field without help.
  CounterTable(std::initializer_list<Field> fields) : fields_(fields) {
    std::set<std::string> keys;
    for (const Field& f : fields_) {
      if (!keys.insert(f.key).second) throw std::logic_error(std::string("CounterTable: key twice: ") + f.key);
      if (std::string(f.help).empty()) throw std::logic_error(std::string("CounterTable: no help for ") + f.key);
    }
  }
  /// The values of `s`, in the table's order.
  std::vector<Counter> counters(const S& s) const {
    std::vector<Counter> out;
    out.reserve(fields_.size());
    for (const Field& f : fields_) {
      const double v = std::visit([&s](auto m) { return static_cast<double>(s.*m); }, f.member);
      out.push_back({f.key, v, f.warn_on_growth});
    }
    return out;
  }
  std::vector<CounterSpec> specs() const {
    std::vector<CounterSpec> out;
    for (const Field& f : fields_) out.push_back({f.key, f.help, f.warn_on_growth});
    return out;
  }

 private:
  std::vector<Field> fields_;
};

/// Formats a value as the key/value pairs show it: integers without decimals, else 3 decimals.
std::string formatValue(double v);
/// The counters as one log line: "<prefix> key value key value ...".
std::string countersLine(const std::string& prefix, const std::vector<Counter>& counters);

}  // namespace ros_diagnostics
}  // namespace uw_multislam
