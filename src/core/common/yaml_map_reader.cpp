#include "uw_multislam/core/common/yaml_map_reader.h"

namespace uw_multislam {
namespace core {

YAML::Node parseYaml(const std::string& text, const std::string& what) {
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const YAML::Exception& e) {
    throw std::invalid_argument(what + " YAML: " + e.what());
  }
  if (!root || root.IsNull()) root = YAML::Node(YAML::NodeType::Map);
  return root;
}

}  // namespace core
}  // namespace uw_multislam
