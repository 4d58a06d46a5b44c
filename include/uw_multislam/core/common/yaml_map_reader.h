// Reading option structs from YAML maps: every key read into its field, unknown keys rejected
// with the path of the map ("sessions[1].water: unknown key 'turbidty'"), so a typo never falls
// back silently to a default.
#pragma once

#include <yaml-cpp/yaml.h>
#include <Eigen/Core>

#include <cmath>
#include <set>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <vector>

#include "uw_multislam/core/frontend/dataset.h"

namespace uw_multislam {
namespace core {

/// Reads the keys of one YAML map into fields; throws std::invalid_argument naming the map.
class MapReader {
 public:
  MapReader(const YAML::Node& node, std::string where) : node_(node), where_(std::move(where)) {
    if (present() && !node_.IsMap()) fail("must be a map");
  }
  // Call after the last read: rejects every key that was not read.
  void finish() const {
    if (!present()) return;
    for (const auto& kv : node_) {
      if (!kv.first.IsScalar()) fail("a key that is not a word (a list or a map as a key)");
      const std::string key = kv.first.as<std::string>();
      if (!used_.count(key)) fail("unknown key '" + key + "'");
    }
  }
  template <typename T>
  void read(const char* key, T* out) {
    used_.insert(key);
    if (!present() || !node_[key]) return;
    // A quoted scalar ("2", '0.5', "true") is text: yaml-cpp would convert it all the same, so a
    // number written as a string (a template's placeholder, a value pasted from JSON) would pass
    // unnoticed where any other text is refused. Its tag is "!" (a plain scalar's is "?").
    if constexpr (std::is_arithmetic_v<T>) {
      refuseQuoted(key, node_[key]);
    } else if constexpr (std::is_same_v<T, std::vector<double>>) {
      if (node_[key].IsSequence())
        for (const YAML::Node& item : node_[key]) refuseQuoted(key, item);
    }
    try {
      *out = node_[key].template as<T>();
    } catch (const YAML::Exception&) {
      fail(std::string("bad value for '") + key + "'");
    }
    // .inf / .nan parse as numbers: no option means anything by them (0 is "off" where there is
    // an off), and an infinite threshold or sigma crashed OpenCV or overflowed a covariance.
    if constexpr (std::is_floating_point_v<T>) {
      if (!std::isfinite(*out)) fail(std::string("bad value for '") + key + "' (not a finite number)");
    } else if constexpr (std::is_same_v<T, std::vector<double>>) {
      for (double x : *out)
        if (!std::isfinite(x)) fail(std::string("bad value for '") + key + "' (not a finite number)");
    }
  }
  void readVector2(const char* key, Eigen::Vector2d* out) { readVector<2>(key, out); }
  void readVector3(const char* key, Eigen::Vector3d* out) { readVector<3>(key, out); }
  YAML::Node child(const char* key) {
    used_.insert(key);
    return present() ? node_[key] : YAML::Node();
  }
  /// A missing or null (empty) map reads as "all defaults".
  bool present() const { return node_ && !node_.IsNull(); }
  [[noreturn]] void fail(const std::string& what) const { throw std::invalid_argument(where_ + ": " + what); }
  const std::string& where() const { return where_; }

 private:
  template <int N, typename V>
  void readVector(const char* key, V* out) {
    std::vector<double> v;
    read(key, &v);
    if (!present() || !node_[key]) return;
    if (static_cast<int>(v.size()) != N) fail(std::string("'") + key + "' needs " + std::to_string(N) + " numbers");
    for (int i = 0; i < N; ++i) (*out)[i] = v[i];
  }
  void refuseQuoted(const char* key, const YAML::Node& value) const {
    if (value.IsScalar() && value.Tag() == "!")
      fail(std::string("bad value for '") + key + "': \"" + value.Scalar() +
           "\" is quoted text, not a number (write it without quotes)");
  }
  const YAML::Node node_;
  std::string where_;
  std::set<std::string> used_;
};

/// Parses YAML text; a syntax error becomes std::invalid_argument("<what> YAML: ..."). An empty
/// document is an empty map (all defaults).
YAML::Node parseYaml(const std::string& text, const std::string& what);

/// Reads a YAML file and hands its text to `parse`; an unreadable file throws DatasetError and
/// a bad one std::invalid_argument, both starting with the path.
template <typename Parse>
auto parseYamlFile(const std::string& path, Parse parse) -> decltype(parse(std::string())) {
  const std::string text = readTextFile(path);
  try {
    return parse(text);
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(path + ": " + e.what());
  } catch (const YAML::Exception& e) {  // one the readers did not turn into a message of their own
    throw std::invalid_argument(path + ": " + e.what());
  }
}

}  // namespace core
}  // namespace uw_multislam
