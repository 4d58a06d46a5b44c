// config/default.yaml and the options structs agree: each node's options are read twice, once
// from an empty parameter tree (every member keeps its default) and once from config/default.yaml
// loaded as rosparam loads it (PyYAML's YAML 1.1 types), and the reads (ros_params::Params records
// each) must match: every key of the file is read and holds the struct's default, and every
// parameter read is in the file, or on the list below of keys the file documents in a comment only
// (optional features off by default). config/onboard.yaml, a preset over it, may change values but
// has no key that nothing reads. config/slam.yaml is checked against core::SlamConfig by pytest
// test_offline_slam (test_config_slam_yaml_documents_the_defaults).
#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>

#include <fstream>
#include <map>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "uw_multislam/ros/odometry_options.h"
#include "uw_multislam/ros/slam_params.h"
#include "uw_multislam/ros/typed_params.h"

namespace uw_multislam {
namespace {

using XmlRpc::XmlRpcValue;

constexpr char kNs[] = "/uw_multislam";

// Read by a node, absent from config/default.yaml on purpose: their default turns a feature off
// (or is a path under $ROS_HOME), and the file shows each in a commented example.
const std::set<std::string> kDocumentedInACommentOnly = {
    "backend_node/store_path",          "backend_node/export_root",       "backend_node/datum/latitude_deg",
    "backend_node/datum/longitude_deg", "backend_node/datum/heading_deg", "backend_node/datum/altitude_m",
    "backend_node/datum/earth_frame",   "backend_node/datum/utm_frame",   "backend_node/fleet/vehicle",
    "backend_node/fleet/peers",         "backend_node/fleet/hash_codes",  "backend_node/fleet/peer_timeout_s"};

// Keys whose value in config/default.yaml is not the struct's on purpose: the split loop
// detectors are one nodelet type run in two modes.
const std::map<std::string, XmlRpcValue> kNotTheDefault = {{"local_loops_node/mode", XmlRpcValue("local")},
                                                           {"global_loops_node/mode", XmlRpcValue("global")}};

std::string readText(const std::string& path) {
  std::ifstream in(path);
  EXPECT_TRUE(in) << path;
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

// A plain scalar as PyYAML's resolver (YAML 1.1, rosparam's reader) types it; quoted: text.
XmlRpcValue scalarAsRosparam(const YAML::Node& n) {
  const std::string& s = n.Scalar();
  if (n.Tag() == "!") return XmlRpcValue(s);
  static const std::regex yes(R"(yes|Yes|YES|true|True|TRUE|on|On|ON)");
  static const std::regex no(R"(no|No|NO|false|False|FALSE|off|Off|OFF)");
  static const std::regex integer(R"([-+]?(0|[1-9][0-9_]*))");
  static const std::regex real(R"([-+]?([0-9][0-9_]*)?\.[0-9_]*([eE][-+][0-9]+)?)");
  if (std::regex_match(s, yes)) return XmlRpcValue(true);
  if (std::regex_match(s, no)) return XmlRpcValue(false);
  const std::string digits = std::regex_replace(s, std::regex("_"), "");
  if (std::regex_match(s, integer)) return XmlRpcValue(std::stoi(digits));
  if (std::regex_match(s, real) && s != "." && s != "-." && s != "+.") return XmlRpcValue(std::stod(digits));
  EXPECT_FALSE(s.empty() || s == "~" || s == "null") << "a null value: rosparam cannot load it";
  return XmlRpcValue(s);
}

XmlRpcValue asRosparam(const YAML::Node& n) {
  XmlRpcValue v;
  if (n.IsMap()) {
    v.begin();  // a map even when empty
    for (const auto& kv : n) v[kv.first.as<std::string>()] = asRosparam(kv.second);
  } else if (n.IsSequence()) {
    for (std::size_t i = 0; i < n.size(); ++i) v[static_cast<int>(i)] = asRosparam(n[i]);
  } else {
    v = scalarAsRosparam(n);
  }
  return v;
}

XmlRpcValue loadAsRosparam(const std::string& file) {
  return asRosparam(YAML::Load(readText(std::string(UWMS_SOURCE_DIR) + "/config/" + file)));
}

// `over` merged into `tree` key by key, as rosparam load does with a second file.
void overlay(XmlRpcValue* tree, const XmlRpcValue& over) {
  for (const auto& [key, value] : over) {
    if (value.getType() == XmlRpcValue::TypeStruct && tree->hasMember(key) &&
        (*tree)[key].getType() == XmlRpcValue::TypeStruct)
      overlay(&(*tree)[key], value);
    else
      (*tree)[key] = value;
  }
}

// The reads of every node of slam.launch (both loop detector layouts) from the pipeline's
// namespace `tree`, by name relative to it ("backend_node/queue_size", "frames/map_frame").
std::map<std::string, ros_params::ParamRead> readAll(const XmlRpcValue& tree) {
  const ros_params::Params nh(tree, kNs);
  ros_params::backendNodeletOptions(nh, nh.child("backend_node"));
  ros_params::odometryNodeletOptions(nh, nh.child("odometry_node"));
  for (const char* node : {"loop_detector_node", "local_loops_node", "global_loops_node"})
    ros_params::loopDetectorNodeletOptions(nh.child(node));
  std::map<std::string, ros_params::ParamRead> reads;
  const std::string prefix = std::string(kNs) + "/";
  for (const ros_params::ParamRead& r : nh.reads()) {
    EXPECT_EQ(r.name.rfind(prefix, 0), 0u) << r.name;
    const std::string name = r.name.substr(prefix.size());
    // A key read twice (frames/ by two nodes) must have the same default both times.
    const auto [at, inserted] = reads.emplace(name, r);
    if (!inserted) {
      EXPECT_EQ(at->second.value, r.value) << name << " read twice with two values";
    }
  }
  return reads;
}

// The leaves of `tree` by relative name ("backend_node/queue_size"); the slam tree is not walked.
void leaves(const XmlRpcValue& tree, const std::string& prefix, std::map<std::string, XmlRpcValue>* out) {
  for (const auto& [key, value] : tree) {
    const std::string name = prefix.empty() ? key : prefix + "/" + key;
    if (name == "slam") continue;
    if (value.getType() == XmlRpcValue::TypeStruct)
      leaves(value, name, out);
    else
      (*out)[name] = value;
  }
}

std::vector<std::string> disagreements(const XmlRpcValue& file, const std::string& file_text) {
  std::vector<std::string> problems;
  const auto defaults = readAll(XmlRpcValue());
  const auto from_file = readAll(file);
  for (const auto& [name, read] : defaults) {
    EXPECT_FALSE(read.set) << name << " is set in an empty tree";
  }
  for (const auto& [name, read] : from_file) {
    const auto not_default = kNotTheDefault.find(name);
    const XmlRpcValue& expected = not_default != kNotTheDefault.end() ? not_default->second : defaults.at(name).value;
    if (read.set && !(read.value == expected))
      problems.push_back(name + ": " + ros_params::shownValue(read.value) + " in the file, " +
                         ros_params::shownValue(expected) + " in the struct");
    if (!read.set && !kDocumentedInACommentOnly.count(name)) problems.push_back(name + " is read but not in the file");
    if (!read.set && kDocumentedInACommentOnly.count(name)) {
      const std::string key = name.substr(name.rfind('/') + 1);
      if (!std::regex_search(file_text, std::regex("\n *#[^\n]*\\b" + key + ":")))
        problems.push_back(name + " is on the list of keys documented in a comment, but no comment shows " + key + ":");
    }
  }
  std::map<std::string, XmlRpcValue> keys;
  leaves(file, "", &keys);
  for (const auto& [name, value] : keys)
    if (!from_file.count(name) || !from_file.at(name).set) problems.push_back(name + " is in the file but not read");
  return problems;
}

std::string joined(const std::vector<std::string>& lines) {
  std::string s;
  for (const std::string& l : lines) s += l + "\n";
  return s;
}

TEST(ConfigDefaults, DefaultYamlHoldsEveryParameterAtTheStructsDefault) {
  const XmlRpcValue file = loadAsRosparam("default.yaml");
  const std::vector<std::string> problems =
      disagreements(file, readText(std::string(UWMS_SOURCE_DIR) + "/config/default.yaml"));
  EXPECT_TRUE(problems.empty()) << "config/default.yaml and the options structs disagree:\n" << joined(problems);
}

TEST(ConfigDefaults, EachSideChangedAloneIsFound) {
  const std::string text = readText(std::string(UWMS_SOURCE_DIR) + "/config/default.yaml");
  XmlRpcValue file = loadAsRosparam("default.yaml");
  file["backend_node"]["max_keyframe_gap"] = 1000;  // the loop detector's value, in the back-end's block
  file["odometry_node"]["sesion_gap_s"] = 10.0;     // a misspelt key
  const std::vector<std::string> problems = disagreements(file, text);
  EXPECT_EQ(problems.size(), 2u) << joined(problems);
  EXPECT_NE(joined(problems).find("backend_node/max_keyframe_gap: 1000 in the file, 32 in the struct"),
            std::string::npos)
      << joined(problems);
  EXPECT_NE(joined(problems).find("odometry_node/sesion_gap_s is in the file but not read"), std::string::npos)
      << joined(problems);
  XmlRpcValue without = loadAsRosparam("default.yaml");
  XmlRpcValue odometry;
  odometry.begin();
  for (const auto& [key, value] : without["odometry_node"])
    if (key != "nav_buffer_s") odometry[key] = value;
  without["odometry_node"] = odometry;
  EXPECT_EQ(joined(disagreements(without, text)), "odometry_node/nav_buffer_s is read but not in the file\n");
}

TEST(ConfigDefaults, TheOnboardPresetHasNoKeyThatNothingReads) {
  XmlRpcValue tree = loadAsRosparam("default.yaml");
  const XmlRpcValue onboard = loadAsRosparam("onboard.yaml");
  XmlRpcValue slam;
  slam["slam"] = loadAsRosparam("slam.yaml");
  overlay(&tree, slam);
  overlay(&tree, onboard);
  const auto reads = readAll(tree);  // the slam block (slam.yaml with the preset's) is validated here
  std::map<std::string, XmlRpcValue> keys;
  leaves(onboard, "", &keys);
  EXPECT_FALSE(keys.empty());
  for (const auto& [name, value] : keys) {
    ASSERT_TRUE(reads.count(name)) << name << ": in config/onboard.yaml but not read";
    EXPECT_EQ(reads.at(name).value, value) << name;
  }
}

}  // namespace
}  // namespace uw_multislam
