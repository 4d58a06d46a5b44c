#include "uw_multislam/core/common/atomic_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <ostream>
#include <random>
#include <streambuf>
#include <vector>

namespace uw_multislam {
namespace core {

namespace {

std::string errnoText(int err) { return std::strerror(err); }

// Writes everything, retrying short writes and interruptions; false with errno set on a failure.
bool writeAll(int fd, const char* data, std::size_t n) {
  while (n > 0) {
    const ssize_t w = ::write(fd, data, n);
    if (w < 0) {
      if (errno == EINTR) continue;
      return false;
    }
    data += w;
    n -= static_cast<std::size_t>(w);
  }
  return true;
}

std::string randomLetters(int n) {
  static const char kLetters[] = "abcdefghijklmnopqrstuvwxyz0123456789";
  thread_local std::mt19937_64 engine{std::random_device{}()};
  std::uniform_int_distribution<int> pick(0, static_cast<int>(sizeof kLetters) - 2);
  std::string s;
  for (int i = 0; i < n; ++i) s += kLetters[pick(engine)];
  return s;
}

}  // namespace

OutputModes outputModesOf(const std::string& source) {
  OutputModes m;
  struct stat st {};
  if (source.empty() || ::stat(source.c_str(), &st) != 0) return m;
  m.file = st.st_mode & 0666;
  m.directory = m.file | ((m.file & 0444) >> 2);  // x wherever r: 0600 -> 0700, 0640 -> 0750
  return m;
}

void makeDirectories(const std::string& path, mode_t mode) {
  namespace fs = std::filesystem;
  std::error_code ec;
  fs::path prefix;
  for (const fs::path& part : fs::path(path).lexically_normal()) {
    if (part.empty()) continue;  // the empty name after a trailing separator
    prefix /= part;
    if (fs::is_directory(prefix, ec)) continue;
    if (::mkdir(prefix.c_str(), mode) != 0) {
      const int err = errno;
      if (err == EEXIST && fs::is_directory(prefix, ec)) continue;  // made meanwhile
      throw FileWriteError(path + ": cannot create the directory " + prefix.string() + ": " + errnoText(err));
    }
  }
}

// A stream buffer writing to a descriptor; the first failure's errno is kept for the message.
class AtomicFile::Buffer : public std::streambuf {
 public:
  explicit Buffer(int fd) : fd_(fd), data_(1 << 16) { setp(data_.data(), data_.data() + data_.size()); }
  int error() const { return error_; }

 protected:
  int_type overflow(int_type c) override {
    if (!drain()) return traits_type::eof();
    if (!traits_type::eq_int_type(c, traits_type::eof())) {
      *pptr() = traits_type::to_char_type(c);
      pbump(1);
    }
    return traits_type::not_eof(c);
  }
  int sync() override { return drain() ? 0 : -1; }

 private:
  bool drain() {
    const std::size_t n = static_cast<std::size_t>(pptr() - pbase());
    if (error_ == 0 && n > 0 && !writeAll(fd_, pbase(), n)) error_ = errno;
    setp(data_.data(), data_.data() + data_.size());
    return error_ == 0;
  }
  int fd_;
  int error_ = 0;
  std::vector<char> data_;
};

AtomicFile::AtomicFile(const std::string& path, mode_t mode) : path_(path) {
  namespace fs = std::filesystem;
  const fs::path p(path);
  name_ = p.filename().string();
  if (name_.empty() || name_ == "." || name_ == "..")
    throw FileWriteError(path + ": not a file name (it names a directory)");
  directory_ = p.parent_path().empty() ? std::string(".") : p.parent_path().string();
  dir_fd_ = ::open(directory_.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dir_fd_ < 0) throw FileWriteError(path + ": cannot open its directory " + directory_ + ": " + errnoText(errno));
  // Exclusive and without following a link: an existing name (a link planted there, another
  // writer's temporary, a crash's leftover) is never opened, another name is tried instead.
  for (int attempt = 0; attempt < 100 && fd_ < 0; ++attempt) {
    const std::string candidate = name_ + ".tmp" + (attempt == 0 ? "" : "." + randomLetters(6));
    fd_ = ::openat(dir_fd_, candidate.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, mode);
    if (fd_ >= 0) {
      temporary_ = candidate;
    } else if (errno != EEXIST) {
      const int err = errno;
      ::close(dir_fd_);
      dir_fd_ = -1;
      throw FileWriteError(path + ": cannot create the temporary " + candidate + " in " + directory_ + ": " +
                           errnoText(err));
    }
  }
  if (fd_ < 0) {
    ::close(dir_fd_);
    dir_fd_ = -1;
    throw FileWriteError(path + ": cannot create a temporary in " + directory_ + ": 100 names taken");
  }
  buffer_ = std::make_unique<Buffer>(fd_);
  stream_ = std::make_unique<std::ostream>(buffer_.get());
}

AtomicFile::~AtomicFile() {
  if (!committed_) discard();
  if (dir_fd_ >= 0) ::close(dir_fd_);
}

std::ostream& AtomicFile::stream() { return *stream_; }

std::string AtomicFile::reopenPath() const {
  const std::string proc = "/proc/self/fd/" + std::to_string(fd_);
  struct stat by_proc {
  }, mine{};
  if (::stat(proc.c_str(), &by_proc) == 0 && ::fstat(fd_, &mine) == 0 && by_proc.st_ino == mine.st_ino &&
      by_proc.st_dev == mine.st_dev)
    return proc;
  return (std::filesystem::path(directory_) / temporary_).string();
}

bool AtomicFile::temporaryIs(const struct stat& mine) const {
  struct stat there {};
  return ::fstatat(dir_fd_, temporary_.c_str(), &there, AT_SYMLINK_NOFOLLOW) == 0 && mine.st_dev == there.st_dev &&
         mine.st_ino == there.st_ino;
}

void AtomicFile::discard() noexcept {
  if (fd_ < 0) return;
  // Only the file created here: a name swapped meanwhile (by whoever can write the directory) is
  // not ours to remove.
  struct stat mine {};
  const bool ours = ::fstat(fd_, &mine) == 0 && temporaryIs(mine);
  ::close(fd_);
  fd_ = -1;
  if (ours) ::unlinkat(dir_fd_, temporary_.c_str(), 0);
}

void AtomicFile::commit() {
  if (committed_) return;
  stream_->flush();
  int err = buffer_->error();
  if (err == 0 && !*stream_) err = EIO;
  if (err != 0) {
    discard();
    throw FileWriteError(path_ + ": write failed: " + errnoText(err));
  }
  struct stat mine {};
  if (::fstat(fd_, &mine) != 0) {
    err = errno;
    discard();
    throw FileWriteError(path_ + ": cannot stat the temporary " + temporary_ + ": " + errnoText(err));
  }
  // Closed before the rename: a close that fails (a delayed write error) fails the file.
  const int closed = ::close(fd_);
  err = errno;
  fd_ = -1;
  if (closed != 0) {
    if (temporaryIs(mine)) ::unlinkat(dir_fd_, temporary_.c_str(), 0);
    throw FileWriteError(path_ + ": write failed on close: " + errnoText(err));
  }
  // The name must still hold the file written here: renameat moves whatever the name holds (a link
  // swapped in by whoever can write the directory would become the final name).
  if (!temporaryIs(mine))
    throw FileWriteError(path_ + ": its temporary " + temporary_ + " was replaced while it was written; not renamed");
  if (::renameat(dir_fd_, temporary_.c_str(), dir_fd_, name_.c_str()) != 0) {
    err = errno;
    if (temporaryIs(mine)) ::unlinkat(dir_fd_, temporary_.c_str(), 0);
    throw FileWriteError(path_ + ": cannot rename " + temporary_ + " to it: " + errnoText(err));
  }
  committed_ = true;
}

void writeFileAtomically(const std::string& path, const std::function<void(std::ostream&)>& fill, mode_t mode) {
  AtomicFile f(path, mode);
  fill(f.stream());
  f.commit();
}

void writeFileAtomically(const std::string& path, const std::string& bytes, mode_t mode) {
  AtomicFile f(path, mode);
  if (!writeAll(f.fd(), bytes.data(), bytes.size())) {
    const int err = errno;
    throw FileWriteError(path + ": write failed: " + errnoText(err));
  }
  f.commit();
}

}  // namespace core
}  // namespace uw_multislam
