#include "uw_multislam/ros/slam_params.h"

#include <cstdlib>

#include <yaml-cpp/yaml.h>

namespace uw_multislam {
namespace ros_params {

namespace {

void emit(YAML::Emitter& out, XmlRpc::XmlRpcValue& v) {
  switch (v.getType()) {
    case XmlRpc::XmlRpcValue::TypeBoolean: out << static_cast<bool>(v); break;
    case XmlRpc::XmlRpcValue::TypeInt: out << static_cast<int>(v); break;
    case XmlRpc::XmlRpcValue::TypeDouble: out << static_cast<double>(v); break;
    case XmlRpc::XmlRpcValue::TypeString: out << static_cast<std::string>(v); break;
    case XmlRpc::XmlRpcValue::TypeArray:
      out << YAML::Flow << YAML::BeginSeq;
      for (int i = 0; i < v.size(); ++i) emit(out, v[i]);
      out << YAML::EndSeq;
      break;
    case XmlRpc::XmlRpcValue::TypeStruct:
      out << YAML::BeginMap;
      for (auto& kv : v) {
        out << YAML::Key << kv.first << YAML::Value;
        emit(out, kv.second);
      }
      out << YAML::EndMap;
      break;
    default: out << YAML::Null; break;  // invalid, date-time, base64: not in our parameters
  }
}

}  // namespace

std::string xmlRpcToYaml(const XmlRpc::XmlRpcValue& value) {
  XmlRpc::XmlRpcValue copy = value;  // the accessors are not const
  YAML::Emitter out;
  out.SetDoublePrecision(17);
  emit(out, copy);
  return out.c_str();
}

core::SlamConfig slamConfigFromXmlRpc(const XmlRpc::XmlRpcValue& tree, const std::string& where) {
  try {
    if (tree.getType() != XmlRpc::XmlRpcValue::TypeStruct) throw std::invalid_argument("must be a map of blocks");
    return core::slamConfigFromYaml(xmlRpcToYaml(tree));
  } catch (const std::exception& e) {
    throw std::invalid_argument(where + ": " + e.what());
  }
}

core::SlamConfig slamConfigFromParams(const ros::NodeHandle& nh, const std::string& key) {
  XmlRpc::XmlRpcValue tree;
  if (!nh.getParam(key, tree)) return core::SlamConfig();
  return slamConfigFromXmlRpc(tree, nh.resolveName(key));
}

std::string defaultStorePath() {
  const char* ros_home = std::getenv("ROS_HOME");
  const char* home = std::getenv("HOME");
  return (ros_home ? std::string(ros_home) : std::string(home ? home : ".") + "/.ros") + "/uw_multislam/sessions.db";
}

}  // namespace ros_params
}  // namespace uw_multislam
