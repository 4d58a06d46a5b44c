// Every ROS parameter of the nodelets is read through this header: one snapshot of a namespace's
// parameters (Params), read into the members of an options struct, whose initialisers are the
// defaults (fuse's getParam(nh, "name", member) pattern: no default is written in a read), each
// value checked against the member's type before its range is:
//   double  a number (an int is fine: YAML `3` for `3.0`), finite;
//   int     an int, or a double with no fractional part within int's range (`5.0`; `5.5` refused);
//   bool    true or false (not 1, not the text 'true');
//   string  text (not a number, not true/false: quote it in YAML);
//   map of strings  a map whose values are all text.
// Text where a number belongs ('43', a quoted datum) is refused, with one exception: rosparam reads
// YAML with PyYAML (YAML 1.1), which leaves a number with an exponent but no dot or no exponent
// sign (1e-06, 1e6) as text; such text is taken as the number it spells, since the parameter
// server cannot tell it from a quoted one. A refusal is std::invalid_argument
// "<resolved name> = <value>: <why>", so that the node stops with the key named. Tested in
// test/ros/test_typed_params.cpp (the rules on XmlRpc values, no master) and rostest bad_params.
#pragma once

#include <ros/node_handle.h>
#include <xmlrpcpp/XmlRpcValue.h>

#include <map>
#include <memory>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace uw_multislam {
namespace ros_params {

/// `v` as the member's type by the rules above: true with *out set, or false with *why saying what
/// `v` is instead ("text, not a number (write it without quotes)"); *out is unchanged then.
bool fromXmlRpc(const XmlRpc::XmlRpcValue& v, double* out, std::string* why);
bool fromXmlRpc(const XmlRpc::XmlRpcValue& v, int* out, std::string* why);
bool fromXmlRpc(const XmlRpc::XmlRpcValue& v, bool* out, std::string* why);
bool fromXmlRpc(const XmlRpc::XmlRpcValue& v, std::string* out, std::string* why);
bool fromXmlRpc(const XmlRpc::XmlRpcValue& v, std::map<std::string, std::string>* out, std::string* why);

/// The value as the parameter server would hold it (what Params records of each read).
XmlRpc::XmlRpcValue toXmlRpc(double v);
XmlRpc::XmlRpcValue toXmlRpc(int v);
XmlRpc::XmlRpcValue toXmlRpc(bool v);
XmlRpc::XmlRpcValue toXmlRpc(const std::string& v);
XmlRpc::XmlRpcValue toXmlRpc(const std::map<std::string, std::string>& v);

/// Text spelling a number that rosparam's YAML 1.1 reader leaves as text: digits with an exponent
/// but no dot or no exponent sign ("1e-06", "1e6", "2.5e3"). Plain "43" or "4.3" is not one.
bool isRosparamNumberText(const std::string& text);

/// A value for a message: text in single quotes ('43'), anything else as YAML would write it.
std::string shownValue(const XmlRpc::XmlRpcValue& v);

/// One parameter read: its resolved name, the value used (the member's default when it was not
/// set) and whether it was set.
struct ParamRead {
  std::string name;
  XmlRpc::XmlRpcValue value;
  bool set = false;
};

/// A namespace's parameters, fetched once (the nodelets read them at start-up only), and the
/// record of what was read from it and its children. Copies and children share the record.
class Params {
 public:
  /// The parameter server's tree under `nh`'s namespace (empty when nothing is set there).
  /// Throws std::invalid_argument when the namespace holds a value that is not a map.
  explicit Params(const ros::NodeHandle& nh);
  /// A tree given (a test's, or a YAML file's), named `ns` ("/uw_multislam") in messages.
  Params(XmlRpc::XmlRpcValue tree, std::string ns);

  /// The resolved name of a relative `name` ("datum/latitude_deg" -> "<ns>/datum/latitude_deg").
  std::string resolve(const std::string& name) const;
  /// The value at the relative `name` (its parts separated by '/'), or nullptr when not set.
  const XmlRpc::XmlRpcValue* find(const std::string& name) const;
  bool has(const std::string& name) const { return find(name) != nullptr; }
  /// The namespace `name` below this one (empty when not set), sharing this one's record.
  Params child(const std::string& name) const;

  /// Reads `name` into *member when set, by the type rules above (the member keeps its value, the
  /// default, when not set) and records the read. Throws std::invalid_argument
  /// "<resolved name> = <value>: <why>" for a value of another type.
  template <typename T>
  void read(const std::string& name, T* member) const {
    const XmlRpc::XmlRpcValue* v = find(name);
    if (v != nullptr) {
      std::string why;
      if (!fromXmlRpc(*v, member, &why))
        throw std::invalid_argument(resolve(name) + " = " + shownValue(*v) + ": " + why);
    }
    reads_->push_back({resolve(name), toXmlRpc(*member), v != nullptr});
  }

  /// Every read so far, in order, of this Params, its copies and its children.
  const std::vector<ParamRead>& reads() const { return *reads_; }

 private:
  Params(std::shared_ptr<const XmlRpc::XmlRpcValue> root, std::string path, std::string ns,
         std::shared_ptr<std::vector<ParamRead>> reads);

  std::shared_ptr<const XmlRpc::XmlRpcValue> root_;
  std::string path_;  // of this namespace in root_ ("" or "a/b")
  std::string ns_;    // resolved, for messages
  std::shared_ptr<std::vector<ParamRead>> reads_;
};

/// The value shown in a range refusal.
template <typename T>
std::string shownMember(const T& value) {
  return shownValue(toXmlRpc(value));
}

/// Reads `name` into *member (Params::read), then checks it: throws std::invalid_argument
/// "<resolved name> = <value>: must be <requirement>" when `ok(*member)` is false. The default is
/// the member's value before the call: write it in the options struct, never here.
template <typename T, typename Check>
void param(const Params& p, const std::string& name, T* member, Check ok, const std::string& requirement) {
  p.read(name, member);
  if (!ok(static_cast<const T&>(*member)))
    throw std::invalid_argument(p.resolve(name) + " = " + shownMember(*member) + ": must be " + requirement);
}

/// Reads `name` into *member, any value of the member's type.
template <typename T>
void param(const Params& p, const std::string& name, T* member) {
  p.read(name, member);
}

}  // namespace ros_params
}  // namespace uw_multislam
