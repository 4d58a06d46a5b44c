"""scripts/test_summary.py, the CI's verdict: a failure, a skip, a suite that did not run or one
that is not in the expected list each make it fail. And scripts/format_check.sh, one of its suites:
a file clang-format would change fails it, named in its JUnit result."""
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
