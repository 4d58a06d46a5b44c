"""atomic_file: how the Python tools write a file, by the rules of the C++ core/common/atomic_file.h
(doc/robustness_identity.md), so that nothing but the file asked for is ever written.

- The temporary is created in the destination's own directory, through a descriptor of that
  directory, exclusively and without following a link (O_CREAT | O_EXCL | O_NOFOLLOW): a symbolic
  or hard link planted at the temporary's name is never opened (the name counts as taken and another
  is tried) and never removed (it is not ours). Names: "<name>.tmp" first, then "<name>.tmp.XXXXXX".
- The file is flushed and fsync'd, its name checked to still hold the file written here (same
  device and inode: a name swapped meanwhile is not renamed), then renamed over the final name,
  and the directory fsync'd. The rename replaces a link planted at the final name, never what it
  points to, and never writes into a file hard-linked elsewhere. A reader sees the old file or the
  whole new one.
- On any failure the temporary is removed and the final name left as it was; the error is a
  FileWriteError (an OSError) naming the file.
- Permissions: `perms` narrowed by the umask, as open() does.

Use:
    with atomic_file.AtomicFile(path, "w", newline="") as f:   # or "wb"
        csv.writer(f).writerows(rows)                          # committed when the block ends cleanly
    atomic_file.write_atomically(path, text_or_bytes)
    f = atomic_file.open_streaming(path, "w")                  # a file written as it goes (a recorder):
                                                               # placed by the same rules, then appended to
The tools import it from their own directory (where it is installed beside them).
"""
import io
import os
import secrets

__all__ = ["AtomicFile", "FileWriteError", "open_streaming", "write_atomically"]

_TRIES = 100


class FileWriteError(OSError):
    """A write refused or failed; the message names the file."""


def _same_file(a, b):
    return a.st_dev == b.st_dev and a.st_ino == b.st_ino


class AtomicFile:
    """A new file for `path`, renamed into place by commit() (or at the end of a `with` block that
    raised nothing; an exception discards it). `mode` is "w" (text) or "wb"; `encoding` and
    `newline` as open()'s."""

    def __init__(self, path, mode="w", encoding="utf-8", newline=None, perms=0o666):
        self.temporary = self.file = None
        self._committed = False
        self._dir_fd = self._fd = -1
        if mode not in ("w", "wb"):
            raise ValueError("AtomicFile: mode %r (w or wb)" % mode)
        self.path = os.fspath(path)
        directory, self.name = os.path.split(self.path)
        if self.name in ("", ".", ".."):
            raise FileWriteError("%s: not a file name (it names a directory)" % self.path)
        self.directory = directory or "."
        try:
            self._dir_fd = os.open(self.directory, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
        except OSError as e:
            raise FileWriteError("%s: cannot open its directory %s: %s" % (self.path, self.directory, e.strerror)) \
                from None
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC
        for attempt in range(_TRIES):
            candidate = self.name + ".tmp" + ("" if attempt == 0 else "." + secrets.token_hex(3))
            try:
                self._fd = os.open(candidate, flags, perms, dir_fd=self._dir_fd)
            except FileExistsError:
                continue  # a planted link, another writer's temporary, a crash's leftover: not ours
            except OSError as e:
                self._close_dir()
                raise FileWriteError("%s: cannot create the temporary %s in %s: %s" % (
                    self.path, candidate, self.directory, e.strerror)) from None
            self.temporary = candidate
            break
        if self._fd < 0:
            self._close_dir()
            raise FileWriteError("%s: cannot create a temporary in %s: %d names taken" % (
                self.path, self.directory, _TRIES))
        self._mine = os.fstat(self._fd)
        raw = io.FileIO(self._fd, "wb", closefd=False)
        buffered = io.BufferedWriter(raw)
        self.file = buffered if mode == "wb" else io.TextIOWrapper(buffered, encoding=encoding, newline=newline)

    def __enter__(self):
        return self.file

    def __exit__(self, kind, value, tb):
        if kind is None:
            self.commit()
        else:
            self.discard()
        return False

    def __del__(self):
        if not self._committed:
            self.discard()

    def _close_dir(self):
        if self._dir_fd >= 0:
            os.close(self._dir_fd)
            self._dir_fd = -1

    def _temporary_is_mine(self):
        try:
            there = os.stat(self.temporary, dir_fd=self._dir_fd, follow_symlinks=False)
        except OSError:
            return False
        return _same_file(there, self._mine)

    def _remove_temporary(self):
        if self._dir_fd >= 0 and self.temporary is not None and self._temporary_is_mine():
            try:
                os.unlink(self.temporary, dir_fd=self._dir_fd)
            except OSError:
                pass

    def discard(self):
        """Removes the temporary (only the file made here); the final name is left as it was."""
        if self._committed or self._fd < 0:
            self._close_dir()
            return
        try:
            if self.file is not None:
                self.file.close()
        except (OSError, ValueError):
            pass
        self._remove_temporary()
        os.close(self._fd)
        self._fd = -1
        self._close_dir()

    def commit(self, keep_open=False):
        """Flushes, fsyncs and renames the temporary over the final name. FileWriteError on any
        failure (the temporary removed, the final name unchanged). With keep_open, the file stays
        open for more writes to the file now at the final name (open_streaming)."""
        if self._committed:
            return
        try:
            self.file.flush()
            os.fsync(self._fd)
        except OSError as e:
            self.discard()
            raise FileWriteError("%s: write failed: %s" % (self.path, e.strerror or e)) from None
        # The name must still hold the file written here: rename moves whatever the name holds (a
        # link swapped in by whoever can write the directory would become the final name).
        if not self._temporary_is_mine():
            self.discard()
            raise FileWriteError("%s: its temporary %s was replaced while it was written; not renamed" % (
                self.path, self.temporary))
        try:
            os.rename(self.temporary, self.name, src_dir_fd=self._dir_fd, dst_dir_fd=self._dir_fd)
        except OSError as e:
            self.discard()
            raise FileWriteError("%s: cannot rename %s to it: %s" % (self.path, self.temporary, e.strerror)) from None
        self._committed = True
        try:
            os.fsync(self._dir_fd)  # the rename itself survives a power cut
        except OSError:
            pass  # some file systems refuse fsync on a directory; the file's data is already on disk
        self._close_dir()
        if not keep_open:
            self.file.close()
            os.close(self._fd)
            self._fd = -1


def write_atomically(path, data, perms=0o666):
    """Writes `data` (str, UTF-8, or bytes) to `path` by the rules above."""
    binary = isinstance(data, (bytes, bytearray, memoryview))
    with AtomicFile(path, "wb" if binary else "w", newline="" if not binary else None, perms=perms) as f:
        f.write(data)


def open_streaming(path, mode="w", encoding="utf-8", newline=None, perms=0o666):
    """A file written as it goes (a recorder's rows): created by AtomicFile's rules and renamed into
    place at once (empty), then written through its own descriptor, so a crash keeps what was
    flushed and a link planted at `path` is replaced, never followed. Returns a file object; the
    caller flushes (and os.fsync(f.fileno()) where it matters) and closes it."""
    a = AtomicFile(path, mode, encoding=encoding, newline=newline, perms=perms)
    a.commit(keep_open=True)
    a.file.close()  # empty, and it does not own the descriptor
    fd, a._fd = a._fd, -1
    return open(fd, mode, encoding=None if mode == "wb" else encoding, newline=newline)
