"""Tests of src/tools/atomic_file.py, the Python tools' writer (the rules of core/common/atomic_file.h)."""
import importlib.util
import os

import pytest

_spec = importlib.util.spec_from_file_location("atomic_file", os.path.join(
    os.path.dirname(os.path.abspath(__file__)), "..", "..", "src", "tools", "atomic_file.py"))
atomic_file = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(atomic_file)
AtomicFile, FileWriteError = atomic_file.AtomicFile, atomic_file.FileWriteError
open_streaming, write_atomically = atomic_file.open_streaming, atomic_file.write_atomically


@pytest.fixture
def dirs(tmp_path):
    out, outside = tmp_path / "out", tmp_path / "outside"
    out.mkdir()
    outside.mkdir()
    victim = outside / "victim.txt"
    victim.write_text("precious\n")
    return out, outside, victim


def entries(d):
    return sorted(os.listdir(d))


def test_writes_text_and_bytes_and_replaces_an_old_file(tmp_path):
    p = tmp_path / "a.csv"
    write_atomically(p, "x,y\n1,2\n")
    assert p.read_text() == "x,y\n1,2\n"
    write_atomically(p, b"\x89PNG")
    assert p.read_bytes() == b"\x89PNG"
    with AtomicFile(p, "w", newline="") as f:
        f.write("a\r\nb\n")
    assert p.read_bytes() == b"a\r\nb\n"  # newline="" writes the text as given
    assert entries(tmp_path) == ["a.csv"]


def test_permissions_follow_perms_narrowed_by_the_umask(tmp_path):
    old = os.umask(0o022)
    try:
        write_atomically(tmp_path / "private", "x", perms=0o600)
        write_atomically(tmp_path / "shared", "x")
    finally:
        os.umask(old)
    assert oct(os.stat(tmp_path / "private").st_mode & 0o777) == "0o600"
    assert oct(os.stat(tmp_path / "shared").st_mode & 0o777) == "0o644"


def test_a_link_planted_at_the_final_name_is_replaced_not_followed(dirs):
    out, outside, victim = dirs
    (out / "metrics.json").symlink_to(victim)
    write_atomically(out / "metrics.json", "{}\n")
    assert victim.read_text() == "precious\n"
    assert not (out / "metrics.json").is_symlink()
    assert (out / "metrics.json").read_text() == "{}\n"
    assert entries(outside) == ["victim.txt"]


def test_a_link_planted_at_the_temporary_name_is_neither_opened_nor_removed(dirs):
    out, outside, victim = dirs
    (out / "a.md.tmp").symlink_to(victim)
    (out / "b.md.tmp").symlink_to(outside / "created.txt")  # dangling: O_CREAT would create it
    write_atomically(out / "a.md", "a\n")
    write_atomically(out / "b.md", "b\n")
    assert victim.read_text() == "precious\n"
    assert entries(outside) == ["victim.txt"]
    assert (out / "a.md.tmp").is_symlink() and (out / "b.md.tmp").is_symlink()  # not ours: left
    assert (out / "a.md").read_text() == "a\n" and (out / "b.md").read_text() == "b\n"
    assert entries(out) == ["a.md", "a.md.tmp", "b.md", "b.md.tmp"]  # the random temporaries renamed away


def test_a_hard_link_at_either_name_is_never_written_through(dirs):
    out, outside, victim = dirs
    os.link(victim, out / "t.csv")
    other = outside / "other.txt"
    other.write_text("other\n")
    os.link(other, out / "u.csv.tmp")
    write_atomically(out / "t.csv", "new\n")
    write_atomically(out / "u.csv", "new\n")
    assert victim.read_text() == "precious\n" and other.read_text() == "other\n"
    assert os.stat(out / "t.csv").st_ino != os.stat(victim).st_ino
    assert (out / "t.csv").read_text() == "new\n" and (out / "u.csv").read_text() == "new\n"
    assert os.stat(out / "u.csv.tmp").st_ino == os.stat(other).st_ino  # left as it was


def test_an_exception_in_the_block_leaves_the_old_file_and_no_temporary(tmp_path):
    p = tmp_path / "r.md"
    p.write_text("old\n")
    with pytest.raises(RuntimeError):
        with AtomicFile(p) as f:
            f.write("half")
            raise RuntimeError("fill failed")
    assert p.read_text() == "old\n"
    assert entries(tmp_path) == ["r.md"]


def test_failures_name_the_file_and_leave_nothing(tmp_path):
    (tmp_path / "d").mkdir()
    with pytest.raises(FileWriteError, match=r"d: cannot rename d.tmp to it"):
        write_atomically(tmp_path / "d", "x")  # a directory at the final name
    assert entries(tmp_path) == ["d"]
    with pytest.raises(FileWriteError, match=r"missing/x.csv: cannot open its directory"):
        write_atomically(tmp_path / "missing" / "x.csv", "x")
    with pytest.raises(FileWriteError, match="not a file name"):
        AtomicFile(str(tmp_path) + "/")
    assert issubclass(FileWriteError, OSError)  # the tools' OSError handlers report it in one line


def test_a_temporary_swapped_while_written_is_not_renamed(dirs):
    out, outside, victim = dirs
    a = AtomicFile(out / "s.csv")
    a.file.write("mine\n")
    os.unlink(out / a.temporary)
    (out / a.temporary).symlink_to(victim)  # whoever can write the directory
    with pytest.raises(FileWriteError, match="was replaced while it was written; not renamed"):
        a.commit()
    assert not os.path.lexists(out / "s.csv")
    assert (out / a.temporary).is_symlink() and victim.read_text() == "precious\n"


def test_open_streaming_places_the_file_at_once_and_keeps_what_was_flushed(dirs):
    out, outside, victim = dirs
    (out / "rows.csv").symlink_to(victim)
    f = open_streaming(out / "rows.csv")
    assert not (out / "rows.csv").is_symlink() and (out / "rows.csv").read_text() == ""
    f.write("a,b\n")
    f.flush()
    assert (out / "rows.csv").read_text() == "a,b\n"  # a crash now keeps the row
    f.write("1,2\n")
    f.close()
    assert (out / "rows.csv").read_text() == "a,b\n1,2\n"
    assert victim.read_text() == "precious\n" and entries(out) == ["rows.csv"]


def test_the_module_says_what_it_exports():
    assert set(atomic_file.__all__) == {"AtomicFile", "FileWriteError", "open_streaming", "write_atomically"}
