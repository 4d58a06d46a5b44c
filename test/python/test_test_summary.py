"""scripts/test_summary.py, the CI's verdict: a failure, a skip, a suite that did not run or one
that is not in the expected list each make it fail. And scripts/format_check.sh, one of its suites:
a file clang-format would change fails it, named in its JUnit result. And
scripts/thread_safety_check.py: a field read without its mutex fails it."""
import json
import os
import shutil
import subprocess

import pytest

SCRIPTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "scripts")
SCRIPT = os.path.join(SCRIPTS, "test_summary.py")
PASS = '<testsuite name="s"><testcase classname="c" name="a"/></testsuite>'


def summary(tmp_path, files, expected):
    results = tmp_path / "results"
    (results / "uw_multislam").mkdir(parents=True)
    for name, xml in files.items():
        (results / "uw_multislam" / name).write_text(xml)
    listed = tmp_path / "expected.txt"
    listed.write_text("# comment\n" + "".join(n + "\n" for n in expected))
    r = subprocess.run(["/usr/bin/python3", SCRIPT, str(results), "--expected", str(listed)], capture_output=True,
                       text=True)
    return r.returncode, r.stdout


def test_all_expected_and_passing_is_green(tmp_path):
    code, out = summary(tmp_path, {"a.xml": PASS, "b.xml": PASS}, ["a.xml", "b.xml"])
    assert code == 0 and out.strip().endswith("2 passed, 0 failed, 0 skipped"), out


def test_a_missing_suite_fails_and_is_named(tmp_path):
    code, out = summary(tmp_path, {"a.xml": PASS}, ["a.xml", "b.xml"])
    assert code == 1 and "FAILED b.xml" in out and "did not run" in out, out


def test_an_unlisted_suite_fails_and_is_named(tmp_path):
    code, out = summary(tmp_path, {"a.xml": PASS, "new.xml": PASS}, ["a.xml"])
    assert code == 1 and "FAILED new.xml" in out and "not in" in out, out


def test_a_skip_fails(tmp_path):
    skipped = '<testsuite name="s"><testcase classname="c" name="a"><skipped/></testcase></testsuite>'
    code, out = summary(tmp_path, {"a.xml": skipped}, ["a.xml"])
    assert code == 1 and "0 passed, 0 failed, 1 skipped" in out, out


def test_a_failure_fails(tmp_path):
    failing = '<testsuite name="s"><testcase classname="c" name="a"><failure message="boom"/></testcase></testsuite>'
    code, out = summary(tmp_path, {"a.xml": failing}, ["a.xml"])
    assert code == 1 and "boom" in out, out


FORMATTED = "int add(int a, int b) { return a + b; }\n"
# Two statements on one line and no spaces: clang-format (Google style) would change both.
UNFORMATTED = "int   add(int a,int b){int c=a+b;return c;}\n"
needs_clang_format = pytest.mark.skipif(shutil.which("clang-format") is None, reason="clang-format not installed")


def format_check(tmp_path, sources):
    """format_check.sh on a tree of its own (the repository's .clang-format, `sources` under src/):
    its exit status, its output, and its JUnit result as the summary reads it."""
    root = tmp_path / "tree"
    (root / "src").mkdir(parents=True)
    (root / "include").mkdir()
    shutil.copy(os.path.join(SCRIPTS, "..", ".clang-format"), root / ".clang-format")
    for name, text in sources.items():
        (root / "src" / name).write_text(text)
    junit = tmp_path / "results" / "uw_multislam" / "format-clang_format.xml"
    r = subprocess.run(["bash", os.path.join(SCRIPTS, "format_check.sh"), "--root", str(root), "--junit", str(junit)],
                       capture_output=True, text=True)
    s = subprocess.run(["/usr/bin/python3", SCRIPT, str(tmp_path / "results")], capture_output=True, text=True)
    return r.returncode, r.stdout + r.stderr, s.returncode, s.stdout


@needs_clang_format
def test_format_check_passes_formatted_sources(tmp_path):
    code, out, summary_code, summary_out = format_check(tmp_path, {"a.cpp": FORMATTED, "b.h": FORMATTED})
    assert code == 0 and "2 files formatted" in out, out
    assert summary_code == 0 and summary_out.strip().endswith("1 passed, 0 failed, 0 skipped"), summary_out


@needs_clang_format
def test_format_check_fails_and_names_an_unformatted_file(tmp_path):
    code, out, summary_code, summary_out = format_check(tmp_path, {"a.cpp": FORMATTED, "bad.cpp": UNFORMATTED})
    assert code == 1 and "1 of 2 files not formatted" in out and "src/bad.cpp" in out, out
    assert "src/a.cpp" not in out.split("--- the first differences")[0], out
    assert summary_code == 1 and "FAILED uw_multislam/format-clang_format.xml" in summary_out, summary_out
    assert "src/bad.cpp" in summary_out, summary_out


def test_format_check_without_sources_fails(tmp_path):
    (tmp_path / "empty").mkdir()
    shutil.copy(os.path.join(SCRIPTS, "..", ".clang-format"), tmp_path / "empty" / ".clang-format")
    r = subprocess.run(["bash", os.path.join(SCRIPTS, "format_check.sh"), "--root", str(tmp_path / "empty")],
                       capture_output=True, text=True)
    assert r.returncode == 1 and "no C++ file" in r.stderr, r.stderr


# scripts/thread_safety_check.py, the suite that runs clang's thread-safety analysis on the core.
GUARDED = """#include "uw_multislam/core/common/thread_annotations.h"
namespace uw_multislam { namespace core {
class Counter {
 public:
  void add() { MutexLock lock(&mutex_); ++n_; }
  %s
 private:
  Mutex mutex_;
  int n_ GUARDED_BY(mutex_) = 0;
};
}  }
"""
LOCKED_READ = "int get() { MutexLock lock(&mutex_); return n_; }"
UNLOCKED_READ = "int get() { return n_; }"  # reads n_ without its mutex
needs_clang = pytest.mark.skipif(shutil.which("clang++") is None, reason="clang++ not installed")


def thread_safety_check(tmp_path, sources):
    """thread_safety_check.py on a tree of its own (the repository's annotations header, `sources`
    under src/core/, and a compile_commands.json naming them): its exit status, its output, and
    its JUnit result as the summary reads it."""
    root = tmp_path / "tree"
    header = root / "include" / "uw_multislam" / "core" / "common"
    header.mkdir(parents=True)
    shutil.copy(os.path.join(SCRIPTS, "..", "include", "uw_multislam", "core", "common", "thread_annotations.h"),
                header)
    (root / "src" / "core").mkdir(parents=True)
    build = tmp_path / "build"
    build.mkdir()
    # GCC's precompiled header as CMake passes it (UWMS_PCH): clang cannot read the .gch beside it.
    (build / "cmake_pch.hxx").write_text("#include <mutex>\n")
    (build / "cmake_pch.hxx.gch").write_bytes(b"gpch.not-for-clang")
    commands = []
    for name, text in sources.items():
        (root / "src" / "core" / name).write_text(text)
        commands.append({"directory": str(build), "file": str(root / "src" / "core" / name),
                         "command": "/usr/bin/c++ -I%s -std=c++17 -O2 -Winvalid-pch -include %s -o x.o -c %s"
                         % (root / "include", build / "cmake_pch.hxx", name)})
    (build / "compile_commands.json").write_text(json.dumps(commands))
    junit = tmp_path / "results" / "uw_multislam" / "thread_safety-core.xml"
    r = subprocess.run(["/usr/bin/python3", os.path.join(SCRIPTS, "thread_safety_check.py"), "--build", str(build),
                        "--root", str(root), "--junit", str(junit)], capture_output=True, text=True)
    s = subprocess.run(["/usr/bin/python3", SCRIPT, str(tmp_path / "results")], capture_output=True, text=True)
    return r.returncode, r.stdout + r.stderr, s.returncode, s.stdout


@needs_clang
def test_thread_safety_check_passes_guarded_fields_and_skips_units_without_annotations(tmp_path):
    code, out, summary_code, summary_out = thread_safety_check(
        tmp_path, {"ok.cpp": GUARDED % LOCKED_READ, "plain.cpp": "int f() { return 1; }\n"})
    assert code == 0 and "1 of 2 core units see the annotations" in out and "all pass" in out, out
    assert summary_code == 0 and summary_out.strip().endswith("1 passed, 0 failed, 0 skipped"), summary_out


@needs_clang
def test_thread_safety_check_fails_on_a_field_read_without_its_mutex(tmp_path):
    code, out, summary_code, summary_out = thread_safety_check(
        tmp_path, {"ok.cpp": GUARDED % LOCKED_READ, "bad.cpp": GUARDED % UNLOCKED_READ})
    assert code == 1 and "FAILED: src/core/bad.cpp" in out and "requires holding mutex 'mutex_'" in out, out
    assert "2 units share 1 precompiled headers" in out, out  # the analysis is as strict with one
    assert summary_code == 1 and "FAILED uw_multislam/thread_safety-core.xml" in summary_out, summary_out
    assert "src/core/bad.cpp" in summary_out and "src/core/ok.cpp" not in summary_out, summary_out
