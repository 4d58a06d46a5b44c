#include "uw_multislam/core/export/export_root.h"

#include <algorithm>
#include <filesystem>

namespace uw_multislam {
namespace core {

bool resolveExportFolder(const std::string& root, const std::string& folder, std::string* out, std::string* why) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (root.empty()) {
    *why = "no export root configured (~export_root is empty): exports are off";
    return false;
  }
  const fs::path base = fs::canonical(root, ec);
  if (ec || !fs::is_directory(base, ec)) {
    *why = "export root '" + root + "' is not an existing directory";
    return false;
  }
  if (folder.find('\0') != std::string::npos) {
    *why = "folder holds a NUL character";
    return false;
  }
  const fs::path asked(folder);
  const fs::path target = folder.empty() ? base : fs::weakly_canonical(asked.is_absolute() ? asked : base / asked, ec);
  if (ec) {
    *why = "folder '" + folder + "' cannot be resolved: " + ec.message();
    return false;
  }
  // Below the root: the root's components are a prefix of the target's.
  const bool below = std::mismatch(base.begin(), base.end(), target.begin(), target.end()).first == base.end();
  if (!below) {
    // Named by role, not by path: the message answers a service's caller (the node logs the paths).
    *why = "folder '" + folder +
           "' resolves outside the export root: give a folder below it (no '..' out of it, no absolute path or "
           "symbolic link elsewhere)";
    return false;
  }
  *out = target.string();
  return true;
}

}  // namespace core
}  // namespace uw_multislam
