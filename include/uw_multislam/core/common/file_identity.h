// A file known by what it is, not by the name it was given: its device and inode numbers. Two
// paths name the same file when their identities are equal, whatever links (hard or symbolic),
// bind mounts, "..", "." or relative spellings lie between them; comparing path strings, even
// canonical ones, misses a hard link and a bind mount.
#pragma once

#include <sys/types.h>

#include <string>

namespace uw_multislam {
namespace core {

struct FileId {
  dev_t device = 0;
  ino_t inode = 0;
  bool operator==(const FileId& o) const { return device == o.device && inode == o.inode; }
  bool operator!=(const FileId& o) const { return !(*this == o); }
  bool operator<(const FileId& o) const { return device != o.device ? device < o.device : inode < o.inode; }
};

/// The identity of what `path` names (a symbolic link followed); false when it cannot be stat'ed
/// (missing, no permission).
bool fileIdOf(const std::string& path, FileId* out);
/// The identity of an open descriptor's file; false when fstat fails.
bool fileIdOf(int fd, FileId* out);
/// Both paths exist and name one file (or one directory).
bool sameFile(const std::string& a, const std::string& b);

}  // namespace core
}  // namespace uw_multislam
