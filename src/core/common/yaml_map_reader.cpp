#include "uw_multislam/core/common/yaml_map_reader.h"

#include <set>
#include <string>
#include <vector>

namespace uw_multislam {
namespace core {

namespace {

// yaml-cpp keeps both entries of a key written twice in one map and node[key] reads the first:
// a second `backend:` block (two configurations pasted together) would be dropped without a
// word. Refused instead, with the key's path and line.
// Each map or sequence is walked once: an alias (&a ... *a) shares its node, and one that refers
// to itself would otherwise recurse for ever (or nested ones blow up exponentially).
void refuseDuplicateKeys(const YAML::Node& node, const std::string& where, const std::string& what,
                         std::vector<YAML::Node>* walked) {
  if (!node.IsSequence() && !node.IsMap()) return;
  for (const YAML::Node& w : *walked)
    if (w.is(node)) return;
  walked->push_back(node);
  if (node.IsSequence()) {
    for (std::size_t i = 0; i < node.size(); ++i)
      refuseDuplicateKeys(node[i], where + "[" + std::to_string(i) + "]", what, walked);
    return;
  }
  std::set<std::string> seen;
  for (const auto& kv : node) {
    if (!kv.first.IsScalar()) continue;  // a complex key (never in our files): not compared
    const std::string key = kv.first.Scalar();
    const std::string path = where.empty() ? key : where + "." + key;
    if (!seen.insert(key).second)
      throw std::invalid_argument(what + " YAML: line " + std::to_string(kv.first.Mark().line + 1) + ": key '" + path +
                                  "' appears twice in its map (the second would be ignored)");
    refuseDuplicateKeys(kv.second, path, what, walked);
  }
}

}  // namespace

YAML::Node parseYaml(const std::string& text, const std::string& what) {
  YAML::Node root;
  try {
    // Every document, so that a second one (after '---') is refused rather than ignored.
    const std::vector<YAML::Node> documents = YAML::LoadAll(text);
    if (documents.size() > 1)
      throw std::invalid_argument(what + " YAML: " + std::to_string(documents.size()) +
                                  " documents (separated by '---'); one is read, so the others would be ignored");
    if (!documents.empty()) root = documents.front();
  } catch (const YAML::Exception& e) {
    throw std::invalid_argument(what + " YAML: " + e.what());
  }
  if (!root || root.IsNull()) root = YAML::Node(YAML::NodeType::Map);
  std::vector<YAML::Node> walked;
  refuseDuplicateKeys(root, "", what, &walked);
  return root;
}

}  // namespace core
}  // namespace uw_multislam
