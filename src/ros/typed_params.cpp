#include "uw_multislam/ros/typed_params.h"

#include <cmath>
#include <cstdlib>
#include <iomanip>
#include <limits>
#include <regex>
#include <utility>

namespace uw_multislam {
namespace ros_params {

using XmlRpc::XmlRpcValue;

namespace {

/// What `v` is, for a refusal: "text", "a number", ...
std::string kindOf(const XmlRpcValue& v) {
  switch (v.getType()) {
    case XmlRpcValue::TypeString:
      return "text";
    case XmlRpcValue::TypeInt:
    case XmlRpcValue::TypeDouble:
      return "a number";
    case XmlRpcValue::TypeBoolean:
      return "true/false";
    case XmlRpcValue::TypeArray:
      return "a list";
    case XmlRpcValue::TypeStruct:
      return "a map";
    default:
      return "a value of another kind";
  }
}

/// The number text spells (isRosparamNumberText), for the numeric members.
bool numberOfText(const XmlRpcValue& v, double* out) {
  if (v.getType() != XmlRpcValue::TypeString) return false;
  const std::string& s = static_cast<const std::string&>(v);
  if (!isRosparamNumberText(s)) return false;
  *out = std::strtod(s.c_str(), nullptr);
  return true;
}

bool notANumber(const XmlRpcValue& v, std::string* why) {
  *why = kindOf(v) + ", not a number" +
         (v.getType() == XmlRpcValue::TypeString ? std::string(" (write it without quotes)") : std::string());
  return false;
}

}  // namespace

bool isRosparamNumberText(const std::string& text) {
  static const std::regex exponent_form(R"([-+]?([0-9]+(\.[0-9]*)?|\.[0-9]+)[eE]([-+]?)[0-9]+)");
  std::smatch m;
  if (!std::regex_match(text, m, exponent_form)) return false;
  // PyYAML reads a dot and a signed exponent (1.0e-06) as a number itself: as text, it was quoted.
  const bool dot = text.find('.') != std::string::npos;
  return !dot || m[3].length() == 0;
}

bool fromXmlRpc(const XmlRpcValue& v, double* out, std::string* why) {
  double d = 0.0;
  if (v.getType() == XmlRpcValue::TypeDouble) {
    d = static_cast<const double&>(v);
  } else if (v.getType() == XmlRpcValue::TypeInt) {
    d = static_cast<const int&>(v);
  } else if (!numberOfText(v, &d)) {
    return notANumber(v, why);
  }
  if (!std::isfinite(d)) {
    *why = "not a finite number";
    return false;
  }
  *out = d;
  return true;
}

bool fromXmlRpc(const XmlRpcValue& v, int* out, std::string* why) {
  if (v.getType() == XmlRpcValue::TypeInt) {
    *out = static_cast<const int&>(v);
    return true;
  }
  double d = 0.0;
  if (v.getType() == XmlRpcValue::TypeDouble) {
    d = static_cast<const double&>(v);
  } else if (!numberOfText(v, &d)) {
    return notANumber(v, why);
  }
  // roscpp would round 2.5 to 3: a whole number written with a dot is fine, a fraction is a mistake.
  if (!std::isfinite(d) || d != std::floor(d) || d < std::numeric_limits<int>::min() ||
      d > std::numeric_limits<int>::max()) {
    *why = "not a whole number within [" + std::to_string(std::numeric_limits<int>::min()) + ", " +
           std::to_string(std::numeric_limits<int>::max()) + "]";
    return false;
  }
  *out = static_cast<int>(d);
  return true;
}

bool fromXmlRpc(const XmlRpcValue& v, bool* out, std::string* why) {
  if (v.getType() != XmlRpcValue::TypeBoolean) {
    *why = kindOf(v) + ", not true or false" +
           (v.getType() == XmlRpcValue::TypeString ? std::string(" (write it without quotes)") : std::string());
    return false;
  }
  *out = static_cast<const bool&>(v);
  return true;
}

bool fromXmlRpc(const XmlRpcValue& v, std::string* out, std::string* why) {
  if (v.getType() != XmlRpcValue::TypeString) {
    *why = kindOf(v) + ", not text" +
           (v.getType() == XmlRpcValue::TypeInt || v.getType() == XmlRpcValue::TypeDouble ||
                    v.getType() == XmlRpcValue::TypeBoolean
                ? std::string(" (quote it)")
                : std::string());
    return false;
  }
  *out = static_cast<const std::string&>(v);
  return true;
}

bool fromXmlRpc(const XmlRpcValue& v, std::map<std::string, std::string>* out, std::string* why) {
  if (v.getType() != XmlRpcValue::TypeStruct) {
    *why = kindOf(v) + ", not a map";
    return false;
  }
  std::map<std::string, std::string> m;
  for (const auto& [key, value] : v) {
    std::string text, not_text;
    if (!fromXmlRpc(value, &text, &not_text)) {
      *why = "'" + key + "': " + not_text;
      return false;
    }
    m[key] = text;
  }
  *out = std::move(m);
  return true;
}

XmlRpcValue toXmlRpc(double v) { return XmlRpcValue(v); }
XmlRpcValue toXmlRpc(int v) { return XmlRpcValue(v); }
XmlRpcValue toXmlRpc(bool v) { return XmlRpcValue(v); }
XmlRpcValue toXmlRpc(const std::string& v) { return XmlRpcValue(v); }
XmlRpcValue toXmlRpc(const std::map<std::string, std::string>& v) {
  XmlRpcValue m;
  m.begin();  // a struct even when empty
  for (const auto& [key, value] : v) m[key] = value;
  return m;
}

std::string shownValue(const XmlRpcValue& v) {
  std::ostringstream os;
  switch (v.getType()) {
    case XmlRpcValue::TypeString:
      os << "'" << static_cast<const std::string&>(v) << "'";
      break;
    case XmlRpcValue::TypeBoolean:
      os << (static_cast<const bool&>(v) ? "true" : "false");
      break;
    case XmlRpcValue::TypeInt:
      os << static_cast<const int&>(v);
      break;
    case XmlRpcValue::TypeDouble:
      os << std::setprecision(12) << static_cast<const double&>(v);
      break;
    case XmlRpcValue::TypeArray:
      os << "a list of " << v.size();
      break;
    case XmlRpcValue::TypeStruct:
      os << "a map of " << v.size();
      break;
    default:
      os << "a value of another kind";
      break;
  }
  return os.str();
}

namespace {

XmlRpcValue fetch(const ros::NodeHandle& nh) {
  XmlRpcValue tree;
  if (!nh.getParam(nh.getNamespace(), tree)) return XmlRpcValue();
  if (tree.getType() != XmlRpcValue::TypeStruct)
    throw std::invalid_argument(nh.getNamespace() + " = " + shownValue(tree) + ": must be a map of parameters");
  return tree;
}

std::string joined(const std::string& a, const std::string& b) {
  if (a.empty()) return b;
  if (b.empty()) return a;
  return a.back() == '/' ? a + b : a + "/" + b;
}

}  // namespace

Params::Params(const ros::NodeHandle& nh) : Params(fetch(nh), nh.getNamespace()) {}

Params::Params(XmlRpcValue tree, std::string ns)
    : Params(std::make_shared<const XmlRpcValue>(std::move(tree)), "", std::move(ns),
             std::make_shared<std::vector<ParamRead>>()) {}

Params::Params(std::shared_ptr<const XmlRpcValue> root, std::string path, std::string ns,
               std::shared_ptr<std::vector<ParamRead>> reads)
    : root_(std::move(root)), path_(std::move(path)), ns_(std::move(ns)), reads_(std::move(reads)) {}

std::string Params::resolve(const std::string& name) const { return joined(ns_, name); }

const XmlRpcValue* Params::find(const std::string& name) const {
  const XmlRpcValue* v = root_.get();
  const std::string path = joined(path_, name);
  std::size_t start = 0;
  while (start <= path.size()) {
    const std::size_t end = std::min(path.find('/', start), path.size());
    const std::string part = path.substr(start, end - start);
    if (!part.empty()) {
      if (v->getType() != XmlRpcValue::TypeStruct || !v->hasMember(part)) return nullptr;
      v = &(*v)[part];
    }
    start = end + 1;
  }
  return v->valid() ? v : nullptr;
}

Params Params::child(const std::string& name) const {
  return Params(root_, joined(path_, name), resolve(name), reads_);
}

}  // namespace ros_params
}  // namespace uw_multislam
