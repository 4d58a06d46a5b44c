#include "uw_multislam/core/common/file_identity.h"

#include <sys/stat.h>

namespace uw_multislam {
namespace core {

bool fileIdOf(const std::string& path, FileId* out) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) return false;
  *out = {st.st_dev, st.st_ino};
  return true;
}

bool fileIdOf(int fd, FileId* out) {
  struct stat st {};
  if (::fstat(fd, &st) != 0) return false;
  *out = {st.st_dev, st.st_ino};
  return true;
}

bool sameFile(const std::string& a, const std::string& b) {
  FileId x, y;
  return fileIdOf(a, &x) && fileIdOf(b, &y) && x == y;
}

}  // namespace core
}  // namespace uw_multislam
