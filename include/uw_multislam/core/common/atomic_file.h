// Writing a file so that nothing but the file asked for is ever written: every file the package
// writes (exports, run outputs, mosaics, world files, GeoTIFFs) goes through AtomicFile.
//
// The temporary is created in the destination's own directory, through a descriptor of that
// directory (openat), exclusively and without following a link (O_CREAT | O_EXCL | O_NOFOLLOW):
// a symbolic link planted at the temporary's name is never opened (the name is taken as in use
// and another one tried), and a link planted at the final name is replaced by the new file
// (renameat replaces the link itself, never what it points to). This is what git, rsync and
// systemd do. A reader sees the old file or the whole new one, never a part; on any failure the
// temporary is removed and nothing else changed.
//
// Temporary names: "<name>.tmp" first (what the fault matrix and the tests plant a link at), then
// "<name>.tmp.XXXXXX" with random letters while a name is taken (a concurrent writer, a crash's
// leftover, a planted link: never removed, it is not ours).
//
// Permissions: the file is created with `mode` narrowed by the umask, as open() does; callers pass
// the permissions of what the output is made from (outputModesOf: a 0600 store gives 0600 files
// and 0700 directories).
//
// Not durable across a power cut (no fsync): outputs can be made again from the store, which is.
#pragma once

#include <sys/stat.h>
#include <sys/types.h>

#include <functional>
#include <iosfwd>
#include <memory>
#include <stdexcept>
#include <string>

namespace uw_multislam {
namespace core {

class FileWriteError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Permission bits for what the package writes (narrowed by the umask).
struct OutputModes {
  mode_t file = 0666;
  mode_t directory = 0777;
};

/// The modes of outputs made from `source` (a session store, a run's folder file): its read and
/// write bits for files, and for directories those plus the search bit wherever reading is allowed
/// (0600 -> 0600 / 0700, 0640 -> 0640 / 0750). The defaults (0666 / 0777, narrowed by the umask)
/// when `source` is empty or cannot be stat'ed.
OutputModes outputModesOf(const std::string& source);

/// Creates `path` and its missing parents (mkdir -p), each new one with `mode` (narrowed by the
/// umask); existing directories keep theirs. Throws FileWriteError naming the directory.
void makeDirectories(const std::string& path, mode_t mode);

class AtomicFile {
 public:
  /// Creates the temporary for `path` (see the file comment). `path`'s directory must exist.
  /// Throws FileWriteError naming the file.
  explicit AtomicFile(const std::string& path, mode_t mode = 0666);
  /// Removes the temporary unless commit() succeeded.
  ~AtomicFile();
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;

  /// The file's contents: a buffered stream on the temporary (its errors fail commit()).
  std::ostream& stream();
  /// The temporary's descriptor (for writing it directly).
  int fd() const { return fd_; }
  /// A path that opens this very temporary, for libraries that only write by path (GDAL): the
  /// descriptor's /proc/self/fd entry, which reopens the inode created here whatever the name in
  /// the directory has become meanwhile (the temporary's own path where /proc is missing).
  std::string reopenPath() const;
  /// The temporary's name in the directory (for tests and messages).
  const std::string& temporaryName() const { return temporary_; }
  const std::string& path() const { return path_; }

  /// Flushes the stream, closes the temporary and renames it to the final name. Throws
  /// FileWriteError (a failed write, a full disk, a directory at the final name): then the
  /// temporary is removed and the final name left as it was.
  void commit();

 private:
  class Buffer;
  void discard() noexcept;
  bool temporaryIs(const struct stat& mine) const;  // the temporary's name still holds the file made here

  std::string path_, directory_, name_, temporary_;
  int dir_fd_ = -1;
  int fd_ = -1;
  bool committed_ = false;
  std::unique_ptr<Buffer> buffer_;
  std::unique_ptr<std::ostream> stream_;
};

/// Writes `path` atomically (AtomicFile) through `fill`; fill's stream errors and its exceptions
/// fail the write (the temporary removed, `path` unchanged).
void writeFileAtomically(const std::string& path, const std::function<void(std::ostream&)>& fill, mode_t mode = 0666);
/// Writes `bytes` to `path` atomically.
void writeFileAtomically(const std::string& path, const std::string& bytes, mode_t mode = 0666);

}  // namespace core
}  // namespace uw_multislam
