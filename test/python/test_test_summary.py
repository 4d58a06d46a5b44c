"""scripts/test_summary.py, the CI's verdict: a failure, a skip, a suite that did not run or one
that is not in the expected list each make it fail (issue 21, 5)."""
import os
import subprocess

SCRIPT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "scripts", "test_summary.py")
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
