// Where the back-end's `export` service may write: a folder below a configured export root.
// The request's folder is resolved against the root and refused when it leaves it: `..` that
// climbs out, an absolute path elsewhere, or a symbolic link (anywhere on the path that exists)
// pointing outside. Symbolic links are resolved (std::filesystem::weakly_canonical) before the
// comparison, so a link inside the root to a folder outside it is refused like its target.
#pragma once

#include <string>

namespace uw_multislam {
namespace core {

/// `folder` (relative to `root`, or absolute) -> the canonical directory to write to, in *out.
/// false with *why (a sentence naming the folder and the root) when the root is not an existing
/// directory, or the folder is not below it (the root itself is allowed). Creates nothing.
bool resolveExportFolder(const std::string& root, const std::string& folder, std::string* out, std::string* why);

}  // namespace core
}  // namespace uw_multislam
