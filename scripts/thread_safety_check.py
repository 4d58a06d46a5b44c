#!/usr/bin/env python3
"""Clang's thread-safety analysis on the core: every translation unit of the core library (and of
its tests) that sees core/common/thread_annotations.h, compiled by clang++ -fsyntax-only with
-Wthread-safety -Wthread-safety-beta -Werror and no other warning (GCC builds the code; clang only
checks the locks: which mutex guards a field, which a function needs, the order two are taken in).

    thread_safety_check.py --build BUILD_DIR [--junit FILE] [--jobs N] [--clang CLANG++] [--root DIR]

BUILD_DIR holds compile_commands.json (CMakeLists.txt exports it): each unit is checked with the
include paths and definitions GCC compiles it with. A unit that does not include the annotations
header, directly or through the repository's headers, declares no capability and is skipped: the
analysis would have nothing to check there. --junit writes one test case per unit checked.

The third-party and standard headers (Eigen, OpenCV, gtest, the standard library) are parsed once:
units compiled with the same flags share a clang precompiled header of the system headers that
two or more of them include (<BUILD_DIR>/thread_safety_pch/). It holds no header of the
repository, so every annotated declaration and function body is still analysed in each unit; a
group whose header does not build is checked without one.
--root: the source tree (default: this script's repository; its test checks a tree of its own).
Exit status 0 only when every unit passes.
"""
import argparse
import concurrent.futures
import json
import os
import re
import shlex
import subprocess
import sys
import time
from xml.sax.saxutils import escape, quoteattr

ANNOTATIONS = "uw_multislam/core/common/thread_annotations.h"
# The core library's sources and the core tests (the core and its test as they are built, not the
# second SIFT build of the same sources).
UNITS = re.compile(r"^(src/core/|test/core/)")
INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"', re.M)
ANALYSIS = ["-fsyntax-only", "-Wno-everything", "-Wthread-safety", "-Wthread-safety-beta", "-Werror"]


def repo_root():
    return os.path.dirname(os.path.dirname(os.path.realpath(__file__)))


def annotated_units(repo, files):
    """The files (repository-relative) that include the annotations header through repository headers."""
    sees = {}

    def resolve(name, here):
        for base in (os.path.join(repo, "include"), os.path.dirname(here), repo):
            path = os.path.normpath(os.path.join(base, name))
            if os.path.isfile(path):
                return path
        return None

    def visit(path, stack):
        if path in sees:
            return sees[path]
        if path in stack:  # an include cycle (pragma once): nothing more there
            return False
        stack.add(path)
        with open(path, encoding="utf-8", errors="replace") as f:
            text = f.read()
        found = False
        for name in INCLUDE.findall(text):
            if name == ANNOTATIONS:
                found = True
                break
            child = resolve(name, path)
            if child and visit(child, stack):
                found = True
                break
        stack.discard(path)
        sees[path] = found
        return found

    return [f for f in files if visit(os.path.join(repo, f), set())]


def system_includes(repo, path, seen=None):
    """The <...> headers a file includes, itself or through the repository's headers, in order."""
    seen = set() if seen is None else seen
    if path in seen:
        return []
    seen.add(path)
    with open(path, encoding="utf-8", errors="replace") as f:
        text = f.read()
    found = []
    for m in re.finditer(r'^\s*#\s*include\s+(?:<([^>]+)>|"([^"]+)")', text, re.M):
        if m.group(1):
            found.append(m.group(1))
            continue
        for base in (os.path.join(repo, "include"), os.path.dirname(path), repo):
            child = os.path.normpath(os.path.join(base, m.group(2)))
            if os.path.isfile(child):
                found += system_includes(repo, child, seen)
                break
    return found


def gcc_flags(entry):
    """The include paths, definitions and language standard of the unit's GCC command. Not the
    precompiled header CMake gives GCC (cmake_pch.hxx, beside its .gch, which clang cannot read):
    the unit includes what it uses."""
    args = entry.get("arguments") or shlex.split(entry["command"])
    keep = []
    i = 1  # args[0]: the compiler
    while i < len(args):
        a = args[i]
        if a in ("-I", "-isystem", "-D", "-include", "-iquote") and i + 1 < len(args):
            if not (a == "-include" and args[i + 1].endswith("cmake_pch.hxx")):
                keep += [a, args[i + 1]]
            i += 2
            continue
        if a.startswith(("-I", "-D", "-isystem", "-std=", "-iquote")):
            keep.append(a)
        i += 1
    return keep


def clang_command(entry, clang, pch=None):
    """The unit's GCC command as clang++ -fsyntax-only with the analysis's flags."""
    return [clang] + gcc_flags(entry) + (["-include-pch", pch] if pch else []) + ANALYSIS + [entry["file"]]


def build_pchs(repo, units, by_file, clang, build):
    """One precompiled header per set of flags that two or more units share: the <...> headers
    that two or more of them include. Returns {unit: pch path}; a group whose header does not
    build (or that has nothing to share) gets none."""
    groups = {}
    for unit in units:
        groups.setdefault(tuple(gcc_flags(by_file[unit])), []).append(unit)
    out_dir = os.path.join(build, "thread_safety_pch")
    os.makedirs(out_dir, exist_ok=True)
    pchs = {}
    for number, (flags, members) in enumerate(sorted(groups.items())):
        if len(members) < 2:
            continue
        counts, order = {}, []
        for unit in members:
            for name in dict.fromkeys(system_includes(repo, by_file[unit]["file"])):
                if name not in counts:
                    order.append(name)
                counts[name] = counts.get(name, 0) + 1
        shared = [name for name in order if counts[name] >= 2]
        if not shared:
            continue
        header = os.path.join(out_dir, "group%d.h" % number)
        with open(header, "w", encoding="utf-8") as f:
            f.write("".join("#include <%s>\n" % name for name in shared))
        pch = header + ".pch"
        proc = subprocess.run([clang] + list(flags) + ["-x", "c++-header", "-Wno-everything", header, "-o", pch],
                              cwd=by_file[members[0]]["directory"], stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, universal_newlines=True)
        if proc.returncode != 0:
            print("thread_safety_check: no precompiled header for %d units (%s): %s"
                  % (len(members), ", ".join(members), proc.stdout.strip().splitlines()[:1]))
            continue
        for unit in members:
            pchs[unit] = pch
    return pchs


def check(entry, clang, pch=None):
    start = time.monotonic()
    proc = subprocess.run(clang_command(entry, clang, pch), cwd=entry["directory"], stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, universal_newlines=True)
    return proc.returncode, proc.stdout, time.monotonic() - start


def write_junit(path, results, error=None):
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    failures = sum(1 for r in results if r[1] != 0) + (1 if error else 0)
    total = sum(r[3] for r in results)
    with open(path, "w", encoding="utf-8") as f:
        f.write('<?xml version="1.0" encoding="UTF-8"?>\n')
        f.write('<testsuite name="thread_safety" tests="%d" failures="%d" errors="0" time="%.1f">\n'
                % (len(results) + (1 if error else 0), failures, total))
        if error:
            f.write('<testcase classname="thread_safety" name="setup"><failure message=%s/></testcase>\n'
                    % quoteattr(error))
        for unit, status, output, seconds in results:
            f.write('<testcase classname="thread_safety" name=%s time="%.1f">' % (quoteattr(unit), seconds))
            if status != 0:
                f.write('<failure message=%s>%s</failure>'
                        % (quoteattr("clang -Wthread-safety found a violation in " + unit), escape(output)))
            f.write("</testcase>\n")
        f.write("</testsuite>\n")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--build", required=True, help="the CMake build directory (compile_commands.json)")
    parser.add_argument("--junit", help="write a JUnit result here")
    parser.add_argument("--jobs", type=int, default=1, help="units checked at a time (default 1)")
    parser.add_argument("--clang", default="clang++", help="the clang++ to run (default clang++)")
    parser.add_argument("--root", default=repo_root(), help="the source tree (default: this repository)")
    args = parser.parse_args()
    repo = os.path.realpath(args.root)

    def fail(message):
        print("thread_safety_check: " + message, file=sys.stderr)
        if args.junit:
            write_junit(args.junit, [], message)
        return 1

    database = os.path.join(args.build, "compile_commands.json")
    if not os.path.isfile(database):
        return fail("no %s (CMakeLists.txt exports it: configure the build again)" % database)
    try:
        version = subprocess.run([args.clang, "--version"], stdout=subprocess.PIPE, universal_newlines=True,
                                 check=True).stdout.splitlines()[0]
    except (OSError, subprocess.CalledProcessError):
        return fail("%s not found (scripts/install_deps.sh installs clang)" % args.clang)
    with open(database, encoding="utf-8") as f:
        entries = json.load(f)
    by_file = {}
    for e in entries:
        path = os.path.realpath(os.path.join(e["directory"], e["file"]))
        if not path.startswith(repo + os.sep):
            continue
        rel = os.path.relpath(path, repo)
        if UNITS.match(rel) and "_vlfeat.dir" not in e.get("output", e.get("command", "")):
            by_file.setdefault(rel, dict(e, file=path))
    units = annotated_units(repo, sorted(by_file))
    if not units:
        return fail("no unit of the core includes %s in %s" % (ANNOTATIONS, database))
    print("thread_safety_check: %d of %d core units see the annotations; %s" % (len(units), len(by_file), version))
    results = []
    before = os.times()
    pchs = build_pchs(repo, units, by_file, args.clang, args.build)
    print("thread_safety_check: %d units share %d precompiled headers"
          % (len(pchs), len(set(pchs.values()))), flush=True)
    with concurrent.futures.ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        for unit, (status, output, seconds) in zip(
                units, pool.map(lambda u: check(by_file[u], args.clang, pchs.get(u)), units)):
            results.append((unit, status, output, seconds))
            print("  %-60s %s  %.1f s" % (unit, "ok" if status == 0 else "FAILED", seconds), flush=True)
            if status != 0:
                print(output, end="", flush=True)
    after = os.times()
    cpu = (after.children_user - before.children_user) + (after.children_system - before.children_system)
    bad = [r[0] for r in results if r[1] != 0]
    print("thread_safety_check: %d units, %.0f s CPU: %s" % (len(results), cpu,
                                                            "all pass" if not bad else "FAILED: " + " ".join(bad)))
    if args.junit:
        write_junit(args.junit, results)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
