// The one writer of every file the package writes (core/common/atomic_file.h): exclusive, no link
// followed, in the destination's directory, renamed into place; and file identities.
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <set>
#include <stdexcept>
#include <string>

#include "../../common/scoped_temp_dir.h"
#include "uw_multislam/core/common/atomic_file.h"
#include "uw_multislam/core/common/file_identity.h"

namespace uw_multislam {
namespace core {
namespace {

namespace fs = std::filesystem;
using testing_util::ScopedTempDir;

std::string readAll(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

void writePlain(const fs::path& p, const std::string& bytes) { std::ofstream(p, std::ios::binary) << bytes; }

std::set<std::string> names(const fs::path& dir) {
  std::set<std::string> out;
  for (const auto& e : fs::directory_iterator(dir)) out.insert(e.path().filename().string());
  return out;
}

int modeOf(const fs::path& p) {
  struct stat st {};
  return ::lstat(p.c_str(), &st) == 0 ? static_cast<int>(st.st_mode & 07777) : -1;
}

bool isLink(const fs::path& p) { return fs::is_symlink(fs::symlink_status(p)); }

// The umask of the test process, set for one test and restored.
class ScopedUmask {
 public:
  explicit ScopedUmask(mode_t m) : old_(::umask(m)) {}
  ~ScopedUmask() { ::umask(old_); }

 private:
  mode_t old_;
};

TEST(AtomicFile, ReplacesAnExistingFileByRenameNotByRewriting) {
  ScopedTempDir dir("uwms_atomic");
  const fs::path path = dir.path() / "track.csv";
  writePlain(path, "old contents\n");
  FileId before;
  ASSERT_TRUE(fileIdOf(path.string(), &before));
  std::ifstream reader(path, std::ios::binary);  // a reader that opened the old file keeps reading it whole
  writeFileAtomically(path.string(), std::string("new contents, longer than the old\n"));
  EXPECT_EQ(readAll(path), "new contents, longer than the old\n");
  EXPECT_EQ(std::string(std::istreambuf_iterator<char>(reader), std::istreambuf_iterator<char>()), "old contents\n");
  FileId after;
  ASSERT_TRUE(fileIdOf(path.string(), &after));
  EXPECT_NE(after, before);  // a new inode renamed over the name, never the old one truncated
  EXPECT_EQ(names(dir.path()), std::set<std::string>{"track.csv"});  // no temporary left
  // The stream form writes the same way.
  writeFileAtomically(path.string(), [](std::ostream& f) { f << "x," << 42 << "\n"; });
  EXPECT_EQ(readAll(path), "x,42\n");
  EXPECT_EQ(names(dir.path()), std::set<std::string>{"track.csv"});
}

TEST(AtomicFile, ALinkPlantedAtTheTemporaryNameIsNeverFollowed) {
  ScopedTempDir dir("uwms_atomic");
  ScopedTempDir outside("uwms_atomic_outside");
  const fs::path victim = outside.path() / "victim.txt";
  writePlain(victim, "precious\n");
  const fs::path path = dir.path() / "session_0.tum";
  fs::create_symlink(victim, dir.path() / "session_0.tum.tmp");
  // A dangling link too: what it points to must not be created.
  fs::create_symlink(outside.path() / "created.txt", dir.path() / "map_0.tum.tmp");
  {
    AtomicFile f(path.string(), 0600);
    EXPECT_NE(f.temporaryName(), "session_0.tum.tmp");  // the planted name is taken: another one is used
    EXPECT_EQ(f.temporaryName().rfind("session_0.tum.tmp.", 0), 0u) << f.temporaryName();
    f.stream() << "1.0 0 0 0 0 0 0 1\n";
    f.commit();
  }
  writeFileAtomically((dir.path() / "map_0.tum").string(), std::string("2.0\n"));
  EXPECT_EQ(readAll(victim), "precious\n");
  EXPECT_FALSE(fs::exists(fs::symlink_status(outside.path() / "created.txt")));
  EXPECT_EQ(readAll(path), "1.0 0 0 0 0 0 0 1\n");
  EXPECT_FALSE(isLink(path));
  // The planted links are not ours: left as they are.
  EXPECT_TRUE(isLink(dir.path() / "session_0.tum.tmp"));
  EXPECT_EQ(fs::read_symlink(dir.path() / "session_0.tum.tmp"), victim);
  EXPECT_EQ(names(dir.path()),
            (std::set<std::string>{"session_0.tum", "session_0.tum.tmp", "map_0.tum", "map_0.tum.tmp"}));
}

TEST(AtomicFile, ALinkPlantedAtTheFinalNameIsReplacedNotWrittenThrough) {
  ScopedTempDir dir("uwms_atomic");
  ScopedTempDir outside("uwms_atomic_outside");
  const fs::path victim = outside.path() / "victim.txt";
  writePlain(victim, "precious\n");
  const fs::path path = dir.path() / "session_0.csv";
  fs::create_symlink(victim, path);
  writeFileAtomically(path.string(), std::string("stamp_s,session\n"));
  EXPECT_EQ(readAll(victim), "precious\n");
  EXPECT_FALSE(isLink(path));  // the link itself was replaced by the new file
  EXPECT_EQ(readAll(path), "stamp_s,session\n");
  EXPECT_EQ(names(dir.path()), std::set<std::string>{"session_0.csv"});
}

TEST(AtomicFile, ATemporarySwappedForALinkWhileWrittenIsNotRenamedAndLibrariesWriteTheFileMadeHere) {
  ScopedTempDir dir("uwms_atomic");
  ScopedTempDir outside("uwms_atomic_outside");
  const fs::path victim = outside.path() / "victim.txt";
  writePlain(victim, "precious\n");
  const fs::path path = dir.path() / "mosaic.png";
  AtomicFile f(path.string(), 0600);
  // What a library that writes by path (GDAL) is given: it opens the temporary made here even
  // after its name was swapped for a link to somewhere else.
  const std::string by_path = f.reopenPath();
  fs::remove(dir.path() / f.temporaryName());
  fs::create_symlink(victim, dir.path() / f.temporaryName());
  FILE* lib = std::fopen(by_path.c_str(), "wb");
  ASSERT_NE(lib, nullptr) << by_path;
  std::fputs("PNG bytes", lib);
  std::fclose(lib);
  EXPECT_EQ(readAll(victim), "precious\n");
  try {
    f.commit();
    FAIL() << "a swapped temporary was renamed into place";
  } catch (const FileWriteError& e) {
    EXPECT_NE(std::string(e.what()).find("was replaced"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(fs::exists(fs::symlink_status(path)));  // the final name never became the link
  EXPECT_EQ(readAll(victim), "precious\n");
}

TEST(AtomicFile, ALibraryWritingByPathFillsTheFileThatIsRenamed) {
  ScopedTempDir dir("uwms_atomic");
  const fs::path path = dir.path() / "mosaic.tif";
  AtomicFile f(path.string(), 0600);
  FILE* lib = std::fopen(f.reopenPath().c_str(), "w+b");  // as GDAL's VSIFOpenL(path, "w+b")
  ASSERT_NE(lib, nullptr);
  std::fputs("II*\n", lib);
  std::fclose(lib);
  EXPECT_FALSE(fs::exists(path));  // nothing at the final name before the commit
  f.commit();
  EXPECT_EQ(readAll(path), "II*\n");
  EXPECT_EQ(modeOf(path), 0600);
  EXPECT_EQ(names(dir.path()), std::set<std::string>{"mosaic.tif"});
}

TEST(AtomicFile, FilesTakeTheModeGivenNarrowedByTheUmask) {
  ScopedTempDir dir("uwms_atomic");
  const ScopedUmask umask(022);
  writeFileAtomically((dir.path() / "a").string(), std::string("a"), 0600);
  writeFileAtomically((dir.path() / "b").string(), std::string("b"), 0640);
  writeFileAtomically((dir.path() / "c").string(), std::string("c"));
  EXPECT_EQ(modeOf(dir.path() / "a"), 0600);
  EXPECT_EQ(modeOf(dir.path() / "b"), 0640);
  EXPECT_EQ(modeOf(dir.path() / "c"), 0644);
  // Replacing a 0644 file with mode 0600 gives 0600 (the new inode's mode, not the old one's).
  writeFileAtomically((dir.path() / "c").string(), std::string("c2"), 0600);
  EXPECT_EQ(modeOf(dir.path() / "c"), 0600);

  // Outputs made from a source take its permissions: files its rw bits, directories x where r.
  const fs::path store = dir.path() / "maps.db";
  writePlain(store, "");
  ::chmod(store.c_str(), 0600);
  EXPECT_EQ(outputModesOf(store.string()).file, 0600u);
  EXPECT_EQ(outputModesOf(store.string()).directory, 0700u);
  ::chmod(store.c_str(), 0640);
  EXPECT_EQ(outputModesOf(store.string()).file, 0640u);
  EXPECT_EQ(outputModesOf(store.string()).directory, 0750u);
  EXPECT_EQ(outputModesOf((dir.path() / "none.db").string()).file, 0666u);  // no source: the defaults
  EXPECT_EQ(outputModesOf("").directory, 0777u);

  const fs::path nested = dir.path() / "out" / "run" / "maps";
  makeDirectories(nested.string() + "/", 0700);
  EXPECT_TRUE(fs::is_directory(nested));
  EXPECT_EQ(modeOf(dir.path() / "out"), 0700);
  EXPECT_EQ(modeOf(nested), 0700);
  ::chmod((dir.path() / "out").c_str(), 0755);
  makeDirectories(nested.string(), 0700);  // existing ones keep theirs
  EXPECT_EQ(modeOf(dir.path() / "out"), 0755);
  writePlain(dir.path() / "file", "x");
  EXPECT_THROW(makeDirectories((dir.path() / "file" / "sub").string(), 0700), FileWriteError);
}

TEST(AtomicFile, ARefusedOrFailedWriteLeavesNothingAndTheOldFileAsItWas) {
  ScopedTempDir dir("uwms_atomic");
  const fs::path path = dir.path() / "loops.csv";
  writePlain(path, "old\n");
  // The filler throws: the old file stays, no temporary is left.
  EXPECT_THROW(writeFileAtomically(path.string(),
                                   [](std::ostream& f) {
                                     f << "half a fi";
                                     throw std::runtime_error("fill failed");
                                   }),
               std::runtime_error);
  EXPECT_EQ(readAll(path), "old\n");
  EXPECT_EQ(names(dir.path()), std::set<std::string>{"loops.csv"});
  // A stream error (what a full disk gives): refused, the same.
  EXPECT_THROW(writeFileAtomically(path.string(), [](std::ostream& f) { f.setstate(std::ios::badbit); }),
               FileWriteError);
  EXPECT_EQ(readAll(path), "old\n");
  EXPECT_EQ(names(dir.path()), std::set<std::string>{"loops.csv"});
  // Never committed: removed.
  { AtomicFile f((dir.path() / "never.csv").string()); }
  EXPECT_EQ(names(dir.path()), std::set<std::string>{"loops.csv"});
  // A directory at the final name: refused, the directory as it was, no temporary left.
  fs::create_directories(dir.path() / "links.csv" / "inside");
  try {
    writeFileAtomically((dir.path() / "links.csv").string(), std::string("x"));
    FAIL() << "a directory was replaced";
  } catch (const FileWriteError& e) {
    EXPECT_NE(std::string(e.what()).find("links.csv"), std::string::npos) << e.what();
  }
  EXPECT_TRUE(fs::is_directory(dir.path() / "links.csv" / "inside"));
  EXPECT_EQ(names(dir.path()), (std::set<std::string>{"loops.csv", "links.csv"}));
  // A missing directory, a name that is not a file: refused, nothing created.
  EXPECT_THROW(writeFileAtomically((dir.path() / "no" / "such.csv").string(), std::string("x")), FileWriteError);
  EXPECT_FALSE(fs::exists(dir.path() / "no"));
  EXPECT_THROW(AtomicFile((dir.path() / "..").string()), FileWriteError);
  EXPECT_THROW(AtomicFile(dir.path().string() + "/"), FileWriteError);
}

TEST(AtomicFile, TwoWritersOfOneNameEachGetATemporaryOfTheirOwn) {
  ScopedTempDir dir("uwms_atomic");
  const fs::path path = dir.path() / "timing.csv";
  AtomicFile first(path.string()), second(path.string());
  EXPECT_NE(first.temporaryName(), second.temporaryName());
  first.stream() << "first\n";
  second.stream() << "second\n";
  first.commit();
  EXPECT_EQ(readAll(path), "first\n");
  second.commit();  // the last rename wins, whole
  EXPECT_EQ(readAll(path), "second\n");
  EXPECT_EQ(names(dir.path()), std::set<std::string>{"timing.csv"});
}

TEST(FileIdentity, AHardLinkASymbolicLinkAndAnotherSpellingAreTheSameFile) {
  ScopedTempDir dir("uwms_identity");
  const fs::path a = dir.path() / "a.db";
  writePlain(a, "x");
  fs::create_hard_link(a, dir.path() / "hard.db");
  fs::create_symlink(a, dir.path() / "soft.db");
  fs::create_directories(dir.path() / "sub");
  EXPECT_TRUE(sameFile(a.string(), (dir.path() / "hard.db").string()));
  EXPECT_TRUE(sameFile(a.string(), (dir.path() / "soft.db").string()));
  EXPECT_TRUE(sameFile(a.string(), (dir.path() / "sub" / ".." / "a.db").string()));
  writePlain(dir.path() / "copy.db", "x");  // equal bytes, another file
  EXPECT_FALSE(sameFile(a.string(), (dir.path() / "copy.db").string()));
  EXPECT_FALSE(sameFile(a.string(), (dir.path() / "missing.db").string()));
  FileId by_path, by_fd;
  ASSERT_TRUE(fileIdOf((dir.path() / "hard.db").string(), &by_path));
  std::FILE* f = std::fopen(a.c_str(), "rb");
  ASSERT_NE(f, nullptr);
  ASSERT_TRUE(fileIdOf(::fileno(f), &by_fd));
  std::fclose(f);
  EXPECT_EQ(by_path, by_fd);
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
