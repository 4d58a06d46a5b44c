#!/usr/bin/python3
"""Summarises the JUnit XML files that catkin's run_tests wrote.

usage: test_summary.py RESULTS_DIR [--expected FILE]

Prints one line per test suite, then every failing test case with the start of its message,
then the closing line 'N passed, N failed, N skipped'. Exit status 1 when any test failed,
errored or was skipped, when a result file holds no test case, when no test ran at all, and
with --expected FILE (result file names relative to RESULTS_DIR/uw_multislam, one per line, #
comments) when an expected result is missing (its suite did not run) or a result is not listed.
"""
import os
import sys
import xml.etree.ElementTree as ET


def suites_in(path):
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as e:
        return None, "unreadable result file: %s" % e
    if root.tag == "testsuite":
        return [root], None
    return root.findall("testsuite") or [root], None


def main():
    args = sys.argv[1:]
    if not args or args[0] in ("-h", "--help") or len(args) not in (1, 3) or (len(args) == 3 and args[1] != "--expected"):
        print(__doc__.strip())
        return 0 if args and args[0] in ("-h", "--help") else 2
    results = args[0]
    expected = None
    if len(args) == 3:
        with open(args[2]) as f:
            expected = {line.strip() for line in f if line.strip() and not line.startswith("#")}
    passed = failed = skipped = 0
    failures = []
    files = []
    for dirpath, _, names in os.walk(results):
        files += [os.path.join(dirpath, n) for n in names if n.endswith(".xml")]
    print("== test summary (%s) ==" % results)
    for path in sorted(files):
        suites, err = suites_in(path)
        name = os.path.relpath(path, results)
        if err:
            failed += 1
            failures.append((name, err))
            continue
        s_pass = s_fail = s_skip = 0
        for suite in suites:
            for case in suite.iter("testcase"):
                label = "%s: %s.%s" % (name, case.get("classname", ""), case.get("name", ""))
                bad = case.find("failure")
                if bad is None:
                    bad = case.find("error")
                if bad is not None:
                    s_fail += 1
                    text = (bad.get("message") or "") + "\n" + (bad.text or "")
                    failures.append((label, text.strip()))
                elif case.find("skipped") is not None or case.get("status") == "notrun":
                    s_skip += 1
                else:
                    s_pass += 1
        if s_pass + s_fail + s_skip == 0:
            s_fail = 1
            failures.append((name, "result file holds no test case (test did not run?)"))
        print("  %-60s %4d passed %3d failed %3d skipped" % (name, s_pass, s_fail, s_skip))
        passed, failed, skipped = passed + s_pass, failed + s_fail, skipped + s_skip
    if not files:
        failed += 1
        failures.append((results, "no result files: no test ran"))
    if expected is not None:
        produced = {os.path.relpath(p, os.path.join(results, "uw_multislam")) for p in files}
        for name in sorted(expected - produced):
            failed += 1
            failures.append((name, "expected result missing: the suite did not run (%s)" % args[2]))
        for name in sorted(produced - expected):
            failed += 1
            failures.append((name, "result not in %s: add it there when you register a suite" % args[2]))
    if skipped:
        failures.append(("skipped tests", "%d test(s) skipped: a skip hides what was not checked" % skipped))
    for label, text in failures:
        print("FAILED %s" % label)
        for line in text.splitlines()[:15]:
            print("    " + line)
    print("%d passed, %d failed, %d skipped" % (passed, failed, skipped))
    return 1 if failed or skipped else 0


if __name__ == "__main__":
    sys.exit(main())
