#include "uw_multislam/core/common/yaml_map_reader.h"

#include <set>
#include <string>

namespace uw_multislam {
namespace core {

namespace {

// yaml-cpp keeps both entries of a key written twice in one map and node[key] reads the first:
// a second `backend:` block (two configurations pasted together) would be dropped without a
// word. Refused instead, with the key's path and line.
void refuseDuplicateKeys(const YAML::Node& node, const std::string& where, const std::string& what) {
  if (node.IsSequence()) {
    for (std::size_t i = 0; i < node.size(); ++i)
      refuseDuplicateKeys(node[i], where + "[" + std::to_string(i) + "]", what);
    return;
  }
  if (!node.IsMap()) return;
  std::set<std::string> seen;
  for (const auto& kv : node) {
    const std::string key = kv.first.IsScalar() ? kv.first.Scalar() : std::string("?");
    const std::string path = where.empty() ? key : where + "." + key;
    if (!seen.insert(key).second)
      throw std::invalid_argument(what + " YAML: line " + std::to_string(kv.first.Mark().line + 1) + ": key '" + path +
                                  "' appears twice in its map (the second would be ignored)");
    refuseDuplicateKeys(kv.second, path, what);
  }
}

}  // namespace

YAML::Node parseYaml(const std::string& text, const std::string& what) {
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const YAML::Exception& e) {
    throw std::invalid_argument(what + " YAML: " + e.what());
  }
  if (!root || root.IsNull()) root = YAML::Node(YAML::NodeType::Map);
  refuseDuplicateKeys(root, "", what);
  return root;
}

}  // namespace core
}  // namespace uw_multislam
