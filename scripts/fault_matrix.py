#!/usr/bin/python3
"""The fault matrix: runs each fault against the offline runner (offline_slam --db) or
the live nodelets (slam.launch on a ROS master of its own) and prints one markdown table row per
case, `| case | expected | observed | verdict |` (held / FAILED), then `N of M held`.

    scripts/fault_matrix.sh [--only SUBSTRING ...] [--offline] [--junit FILE] [--keep]

Every case runs in a temporary directory of its own (live cases with a master of their own on a
free port: it never talks to another master), waits for conditions with deadlines, and stops what
it started and removes its directory even when it fails (--keep leaves the directories). The
survey (make_survey, two short missions, their bags) is generated once and only read.
Exit status 0 only when every case held.
"""
import argparse
import csv
import hashlib
import json
import math
import os
import random
import re
import shutil
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
import traceback
import xml.sax.saxutils


HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
# Two small overlapping dives (make_survey YAML): the tool tests fly the same file.
with open(os.path.join(REPO, "config", "missions", "two_dives.yaml")) as _f:
    SURVEY = _f.read()
sys.path.insert(0, os.path.join(REPO, "src", "tools"))
from atomic_file import write_atomically  # noqa: E402  (the tools' safe writer)


def wait_for(condition, timeout_s, step_s=0.05):
    """Polls condition() until it is true or the deadline passes; returns its last value."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = condition()
        if value or time.monotonic() >= deadline:
            return value
        time.sleep(step_s)


def md5(path):
    with open(path, "rb") as f:
        return hashlib.md5(f.read()).hexdigest()


def ro_connect(path):
    """A read-only connection that never creates or checkpoints anything beside the store."""
    return sqlite3.connect("file:%s?mode=ro" % os.path.abspath(path), uri=True, timeout=5)


def ro_scalar(path, sql):
    """One value read from the store through a read-only connection; None when it cannot be read."""
    try:
        con = ro_connect(path)
        try:
            return con.execute(sql).fetchone()[0]
        finally:
            con.close()
    except sqlite3.Error:
        return None


def keyframe_count(path):
    """Keyframes in the store; None while it cannot be read (not yet created, locked)."""
    return ro_scalar(path, "SELECT count(*) FROM keyframes")


def integrity(path):
    return ro_scalar(path, "PRAGMA integrity_check") or "unreadable"


def session_states(path):
    con = ro_connect(path)
    try:
        return con.execute("SELECT name, state FROM sessions ORDER BY rowid").fetchall()
    finally:
        con.close()


def reason(stderr):
    """The one-line reason of a refusal: stderr's non-empty lines (a clear refusal has exactly one)."""
    return [line for line in stderr.splitlines() if line.strip()]


def short(text, n=150):
    text = " ".join(text.split()).replace("|", "/")
    return text if len(text) <= n else text[: n - 3] + "..."


class Matrix:
    def __init__(self, keep):
        self.keep = keep
        self.rows = []  # (case, expected, observed, held, seconds)

    def row(self, case, expected, observed, held, seconds=0.0):
        observed = re.sub(r"/tmp/uwms_fault_survey\.[^/ ]+/m", "{survey}", observed)
        observed = re.sub(r"/tmp/uwms_fault_[^/ ]+", "{tmp}", observed)
        self.rows.append((case, expected, observed, held, seconds))
        print("| %s | %s | %s | %s |" % (case, expected, short(observed, 400), "held" if held else "FAILED"), flush=True)

    def tempdir(self, case):
        return tempfile.mkdtemp(prefix="uwms_fault_%s." % case.split()[0].replace("/", "_"))

    def done(self, path):
        if not self.keep:
            subprocess.run(["chmod", "-R", "u+w", path], check=False)
            shutil.rmtree(path, ignore_errors=True)


class Offline:
    """offline_slam and make_survey from the workspace's bin directory."""

    def __init__(self, bin_dir, base):
        self.bin = bin_dir
        self.base = base
        with open(os.path.join(base, "survey.yaml"), "w") as f:
            f.write(SURVEY)
        self.survey = os.path.join(base, "m")
        r = subprocess.run([os.path.join(bin_dir, "make_survey"), "--config", os.path.join(base, "survey.yaml"), "--out",
                            self.survey, "--quiet"], capture_output=True, text=True, timeout=120)
        if r.returncode != 0:
            raise RuntimeError("make_survey failed: " + r.stderr)
        # A valid, closed store (session a), for the cases that damage one.
        self.valid_store = os.path.join(base, "valid.db")
        r = self.run(["--session", self.folder("a"), "--out", os.path.join(base, "valid_out"), "--db", self.valid_store])
        if r.returncode != 0 or os.path.exists(self.valid_store + "-wal"):
            raise RuntimeError("the reference store was not written cleanly: " + r.stderr)

    def folder(self, name):
        return os.path.join(self.survey, name)

    def cmd(self, args, quiet=True):
        return [os.path.join(self.bin, "offline_slam")] + (["--quiet"] if quiet else []) + args

    def run(self, args, timeout=180, quiet=True):
        return subprocess.run(self.cmd(args, quiet), capture_output=True, text=True, timeout=timeout)

    def start(self, args, log):
        return subprocess.Popen(self.cmd(args), stdout=log, stderr=subprocess.STDOUT, text=True)


def stop(proc):
    if proc is not None and proc.poll() is None:
        proc.kill()
        proc.wait(timeout=30)


# ---- offline cases -----------------------------------------------------------------------------


def case_kill_offline(m, off):
    case = "offline_slam --db killed -9 mid-run, re-run"
    expected = ("integrity ok; the re-run refused (status 3) in one line naming the folder and --interrupted; "
                "keyframes unchanged; with --interrupted discard: status 0, each folder once, no session recording")
    d = m.tempdir(case)
    proc = None
    try:
        store = os.path.join(d, "s.db")
        args = ["--session", off.folder("a"), "--session", off.folder("b"), "--out", os.path.join(d, "out"), "--db", store]
        with open(os.path.join(d, "run1.log"), "w") as log:
            proc = off.start(args, log)
            got = wait_for(lambda: (keyframe_count(store) or 0) >= 5 or proc.poll() is not None, 60, 0.02)
            if proc.poll() is not None:
                return m.row(case, expected, "the run ended (status %s) before it could be killed" % proc.returncode, False)
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=30)
        before = keyframe_count(store)
        ok = integrity(store)
        states = session_states(store)
        r = off.run(args)
        after = keyframe_count(store)
        lines = reason(r.stderr)
        d2 = off.run(args + ["--interrupted", "discard"])
        states2 = session_states(store)
        held = (bool(got) and ok == "ok" and r.returncode == 3 and len(lines) == 1 and off.folder("a") in lines[0]
                and "--interrupted discard" in lines[0] and after == before and d2.returncode == 0
                and integrity(store) == "ok" and [n for n, _ in states2] == [off.folder("a"), off.folder("b")]
                and all(st == "finished" for _, st in states2))
        observed = ("killed at %d keyframes (sessions %s); integrity %s; re-run status %d: %s; keyframes after %s; "
                    "--interrupted discard: status %d, sessions %s, integrity %s") % (
            before, states, ok, r.returncode, " / ".join(lines) or "(no message)", after, d2.returncode, states2,
            integrity(store))
        m.row(case, expected, observed, held)
    finally:
        stop(proc)
        m.done(d)


def case_two_writers(m, off):
    case = "two offline_slam --db writers on one store"
    expected = "the second refused at once in one line naming the holder; the first exits 0; integrity ok"
    d = m.tempdir(case)
    first = log = None
    try:
        store = os.path.join(d, "s.db")
        log = open(os.path.join(d, "first.log"), "w")
        first = off.start(["--session", off.folder("a"), "--session", off.folder("b"), "--out", os.path.join(d, "o1"), "--db",
                           store], log)
        wait_for(lambda: (keyframe_count(store) or 0) >= 1 or first.poll() is not None, 60, 0.02)
        still_running = first.poll() is None
        r = off.run(["--session", off.folder("b"), "--out", os.path.join(d, "o2"), "--db", store])
        first_running_after = first.poll() is None
        status = first.wait(timeout=180)
        ok = integrity(store)
        lines = reason(r.stderr)
        held = (still_running and first_running_after and r.returncode != 0 and len(lines) == 1 and "in use by pid" in lines[0]
                and status == 0 and ok == "ok")
        observed = "second: status %d, %s (first still running: %s); first: status %d; integrity %s" % (
            r.returncode, " / ".join(lines) or "(no message)", first_running_after, status, ok)
        m.row(case, expected, observed, held)
    finally:
        stop(first)
        if log is not None:
            log.close()
        m.done(d)


def csv_rows(path):
    with open(path) as f:
        return max(0, len([line for line in f.read().splitlines() if line]) - 1)


def case_hard_link_writer(m, off):
    case = "a second offline_slam --db writer through a hard link to the held store"
    expected = ("the second refused at once in one line naming the holder (in use by pid); nothing created beside the "
                "link; the first exits 0; integrity ok; every keyframe of the first run stored")
    d = m.tempdir(case)
    first = log = None
    try:
        store = os.path.join(d, "c3.db")
        hard = os.path.join(d, "c3hard.db")
        log = open(os.path.join(d, "first.log"), "w")
        out1 = os.path.join(d, "o1")
        first = off.start(["--session", off.folder("a"), "--session", off.folder("b"), "--out", out1, "--db", store], log)
        wait_for(lambda: (keyframe_count(store) or 0) >= 1 or first.poll() is not None, 60, 0.02)
        still_running = first.poll() is None
        os.link(store, hard)
        r = off.run(["--session", off.folder("b"), "--out", os.path.join(d, "o2"), "--db", hard, "--again"])
        first_running_after = first.poll() is None
        beside = sorted(f for f in os.listdir(d) if f.startswith("c3hard.db") and f != "c3hard.db")
        status = first.wait(timeout=180)
        ok = integrity(store)
        stored = keyframe_count(store)
        ran = csv_rows(os.path.join(out1, "trajectory.csv")) if status == 0 else None
        lines = reason(r.stderr)
        held = (still_running and first_running_after and r.returncode != 0 and len(lines) == 1
                and "in use by pid %d " % first.pid in lines[0] and hard in lines[0] and not beside and status == 0
                and ok == "ok" and ran is not None and stored == ran)
        observed = ("second: status %d, %s (first still running: %s); beside the link: %s; first: status %d; integrity "
                    "%s; keyframes stored %s of the run's %s") % (
            r.returncode, " / ".join(lines) or "(no message)", first_running_after, beside or "nothing", status, ok,
            stored, ran)
        m.row(case, expected, observed, held)
    finally:
        stop(first)
        if log is not None:
            log.close()
        m.done(d)


def tool(off, name):
    return os.path.join(off.bin, name)


def plant(victims, victim, link, text):
    """A file `victim` holding `text` (outside what a tool writes) and a symbolic link to it at `link`;
    victims[victim] = its md5."""
    with open(victim, "w") as f:
        f.write(text)
    victims[victim] = md5(victim)
    os.symlink(victim, link)


def case_export_planted_links(m, off):
    case = "export_survey over links planted at the temporary and the final names"
    expected = ("status 0; the files outside the export directory byte-identical; every export file a regular file "
                "with the bytes of a clean export; the planted temporary links left as they were")
    d = m.tempdir("export_links")
    try:
        outside = os.path.join(d, "outside")
        os.mkdir(outside)
        ref, out = os.path.join(d, "ref"), os.path.join(d, "out")
        r = subprocess.run([tool(off, "export_survey"), "--db", off.valid_store, "--out", ref, "--quiet"],
                           capture_output=True, text=True, timeout=180)
        if r.returncode != 0:
            return m.row(case, expected, "the clean export failed (status %d): %s" % (r.returncode, short(r.stderr)),
                         False)
        names = sorted(os.listdir(ref))
        os.mkdir(out)
        victims = {}
        for i, name in enumerate(names):
            # The writer's first temporary name, and for one file in two the final name too.
            plant(victims, os.path.join(outside, "tmp_%d" % i), os.path.join(out, name + ".tmp"), "precious %d\n" % i)
            if i % 2 == 0:
                plant(victims, os.path.join(outside, "final_%d" % i), os.path.join(out, name),
                      "precious final %d\n" % i)
        r = subprocess.run([tool(off, "export_survey"), "--db", off.valid_store, "--out", out, "--quiet"],
                           capture_output=True, text=True, timeout=180)
        untouched = all(md5(v) == h for v, h in victims.items()) and sorted(os.listdir(outside)) == sorted(
            os.path.basename(v) for v in victims)
        regular = [n for n in names if os.path.isfile(os.path.join(out, n)) and not os.path.islink(os.path.join(out, n))]
        # The mosaic's PNG is GDAL's: compared as a regular file only; the text files byte for byte.
        same = [n for n in regular if n.endswith(".png") or md5(os.path.join(out, n)) == md5(os.path.join(ref, n))]
        links_left = [n for n in names if os.path.islink(os.path.join(out, n + ".tmp"))]
        held = (r.returncode == 0 and untouched and len(regular) == len(names) and len(same) == len(names)
                and len(links_left) == len(names))
        observed = ("status %d%s; %d files: %d regular, %d equal to the clean export; outside files %s; planted "
                    "temporary links left: %d of %d") % (
            r.returncode, (": " + " / ".join(reason(r.stderr))) if r.returncode else "", len(names), len(regular),
            len(same), "byte-identical" if untouched else "CHANGED", len(links_left), len(names))
        m.row(case, expected, observed, held)
    finally:
        m.done(d)


def case_evaluate_planted_links(m, off):
    case = "evaluate.py over links planted at its report's final names and temporaries"
    expected = ("status 0; the files outside the report byte-identical, nothing created outside; every report file "
                "a regular file; the planted temporary links left as they were")
    d = m.tempdir("evaluate_links")
    try:
        outside, report = os.path.join(d, "outside"), os.path.join(d, "report")
        os.mkdir(outside)
        os.mkdir(report)
        finals = ["metrics.json", "metrics.csv", "metrics.md", "session_0.png", "report.html"]
        temporaries = ["metrics.json.tmp", "report.html.tmp", "map_0.png.tmp"]
        victims = {}
        for name in finals + temporaries:
            plant(victims, os.path.join(outside, name), os.path.join(report, name), "precious %s\n" % name)
        os.symlink(os.path.join(outside, "created"), os.path.join(report, "metrics.md.tmp"))  # dangling
        tool_path = tool(off, "evaluate.py")
        if not os.path.exists(tool_path):
            tool_path = os.path.join(REPO, "src", "tools", "evaluate.py")
        r = subprocess.run(["/usr/bin/python3", tool_path, "--run", os.path.join(off.base, "valid_out"), "--session",
                            off.folder("a"), "--report", report, "--html"], capture_output=True, text=True, timeout=180)
        untouched = all(md5(v) == h for v, h in victims.items()) and sorted(os.listdir(outside)) == sorted(
            os.path.basename(v) for v in victims)
        regular = [n for n in finals if os.path.isfile(os.path.join(report, n))
                   and not os.path.islink(os.path.join(report, n))]
        links_left = [n for n in temporaries + ["metrics.md.tmp"] if os.path.islink(os.path.join(report, n))]
        held = r.returncode == 0 and untouched and len(regular) == len(finals) and len(links_left) == len(temporaries) + 1
        observed = "status %d%s; %d of %d report files regular; outside files %s; planted temporary links left: %d of %d" % (
            r.returncode, (": " + " / ".join(reason(r.stderr)[-2:])) if r.returncode else "", len(regular), len(finals),
            "byte-identical, nothing created" if untouched else "CHANGED", len(links_left), len(temporaries) + 1)
        m.row(case, expected, observed, held)
    finally:
        m.done(d)


def case_restart_ids(m, off):
    case = "session ids across restarts: a killed run discarded, then two more runs on the store"
    expected = ("each session keeps its id and name in every run's start-up list, the store's rows and export_survey's "
                "file names; the discarded session's id is never given again; each run prints its folder -> id "
                "mapping once")
    d = m.tempdir("restart_ids")
    proc = None
    try:
        store = os.path.join(d, "s.db")
        args = ["--session", off.folder("a"), "--out", os.path.join(d, "o1"), "--db", store]
        with open(os.path.join(d, "run1.log"), "w") as log:
            proc = off.start(args, log)
            wait_for(lambda: (keyframe_count(store) or 0) >= 3 or proc.poll() is not None, 60, 0.02)
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=30)
        # Run 2 deletes the killed run's session 0 and processes a again; run 3 adds b; run 4 only restores.
        runs = [off.run(args + ["--interrupted", "discard"], quiet=False),
                off.run(["--session", off.folder("b"), "--out", os.path.join(d, "o3"), "--db", store], quiet=False),
                off.run(["--session", off.folder("a"), "--out", os.path.join(d, "o4"), "--db", store, "--again"],
                        quiet=False)]
        con = ro_connect(store)
        try:
            rows = con.execute("SELECT id, name FROM sessions ORDER BY id").fetchall()
        finally:
            con.close()
        out = os.path.join(d, "export")
        e = subprocess.run([tool(off, "export_survey"), "--db", store, "--out", out, "--quiet", "--no-mosaic"],
                           capture_output=True, text=True, timeout=180)
        exported = sorted(n for n in os.listdir(out) if n.startswith("session_") and n.endswith(".tum")) if \
            e.returncode == 0 else []
        a, b = off.folder("a"), off.folder("b")
        want = [(1, a), (2, b), (3, a + " (2)")]  # a's second session: its name is taken, so " (2)"
        mapping = ["\n  1 %s -> 1 '%s'\n" % (a, a), "\n  2 %s -> 2 '%s'\n" % (b, b), "\n  3 %s -> 3 '%s (2)'\n" % (a, a)]
        printed_once = all(r.stdout.count("session ids (CSV session -> store session ids):") == 1 for r in runs)
        held = (all(r.returncode == 0 for r in runs) and rows == want and exported == ["session_%d.tum" % i for i, _ in want]
                and all(mp in r.stdout for mp, r in zip(mapping, runs)) and printed_once
                and ("restored sessions: 1 '%s' (" % a) in runs[1].stdout
                and ("restored sessions: 1 '%s' (" % a) in runs[2].stdout and ("2 '%s' (" % b) in runs[2].stdout)
        observed = ("statuses %s; store rows %s; export_survey %s; mappings printed %s; run 3 and 4 restored %s / %s") % (
            [r.returncode for r in runs], rows, exported or ("status %d: %s" % (e.returncode, short(e.stderr))),
            [mp.strip() in r.stdout for mp, r in zip(mapping, runs)],
            short(next((l for l in runs[1].stdout.splitlines() if "restored sessions:" in l), "none"), 120),
            short(next((l for l in runs[2].stdout.splitlines() if "restored sessions:" in l), "none"), 120))
        m.row(case, expected, observed, held)
    finally:
        stop(proc)
        m.done(d)


def case_self_merge_hard_link(m, off):
    case = "merge_stores of a store and its hard link"
    expected = "refused (status 1) in one line naming both inputs (given twice); no OUT, no temporary; the input unchanged"
    d = m.tempdir("self_merge")
    try:
        a = os.path.join(d, "a.db")
        shutil.copyfile(off.valid_store, a)
        hard = os.path.join(d, "ahard.db")
        os.link(a, hard)
        before = md5(a)
        out = os.path.join(d, "o.db")
        r = subprocess.run([tool(off, "merge_stores"), out, a, hard], capture_output=True, text=True, timeout=180)
        lines = reason(r.stderr)
        left = sorted(f for f in os.listdir(d) if f not in ("a.db", "ahard.db"))
        held = (r.returncode == 1 and len(lines) == 1 and "given twice" in lines[0] and a in lines[0] and hard in lines[0]
                and not left and md5(a) == before)
        observed = "status %d: %s; left beside the inputs: %s; input %s" % (
            r.returncode, " / ".join(lines) or "(no message)", left or "nothing", "unchanged" if md5(a) == before
            else "CHANGED")
        m.row(case, expected, observed, held)
    finally:
        m.done(d)


def case_index_steps(m, off, bound_ratio=2.5):
    case = ("keyframe index stepped by 1, max_keyframe_gap + 1, 1000, 100000 and 2^20 per message, and by 1000 once "
            "then 1 (bench_store --index-steps)")
    expected = ("no message grows the store by more than %.1f real keyframes (measured in the same run) whatever its "
                "index; a bridged gap of 32 costs under half a keyframe; steps 1000, 100000 and 2^20 refused, growing "
                "nothing; a jump continued by the next keyframe ends the piece: a second session, every keyframe from "
                "the jump on kept" % bound_ratio)
    d = m.tempdir("index_steps")
    try:
        r = subprocess.run([tool(off, "bench_store"), "--index-steps", "--dir", d], capture_output=True, text=True,
                           timeout=300)
        rows = {}
        for line in r.stdout.splitlines():
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            if len(cells) == 9 and cells[0][:1].isdigit():
                key = "jump" if "once" in cells[0] else int(cells[0])
                # messages, accepted, refused, sessions, kept, mean, largest
                rows[key] = [int(c) for c in cells[1:6]] + [float(cells[6]), int(cells[7])]
        real = rows[1][5] if 1 in rows else 0.0
        bound = re.search(r"^bound: .* at most (\d+) bytes", r.stdout, re.M)
        worst = int(bound.group(1)) if bound else -1
        refused = [1000, 100000, 2 ** 20]
        held = (r.returncode == 0 and set(rows) == {1, 33, "jump"} | set(refused) and real > 0 and bound is not None
                and worst == max(v[6] for v in rows.values()) and worst <= bound_ratio * real
                and rows[1][1] == rows[1][0] and rows[33][1] == rows[33][0] and rows[33][6] - real <= 0.5 * real
                and all(rows[s][2] == rows[s][0] and rows[s][6] == 0 for s in refused)
                # the origin and all 10 messages: the jumping one is the new session's first keyframe
                and rows["jump"][3] == 2 and rows["jump"][4] == 1 + rows["jump"][0] and rows["jump"][2] == 1)
        observed = "status %d; %s; %s" % (r.returncode, "; ".join(
            "step %s: %d accepted, %d refused, %d sessions, %d keyframes kept, %.0f kB per message, largest %.0f kB" % (
                s, v[1], v[2], v[3], v[4], v[5] / 1000.0, v[6] / 1000.0) for s, v in rows.items()) or short(r.stderr),
            bound.group(0) if bound else "no bound printed")
        m.row(case, expected, observed, held)
    finally:
        m.done(d)


def case_add_link_yaw_offline(m, off):
    case = "offline_slam --add-link with a yaw of 1e9 rad"
    expected = "refused (status 1) in one line naming the yaw outside [-pi, pi]; the store unchanged"
    d = m.tempdir("add_link_yaw")
    try:
        store = os.path.join(d, "s.db")
        shutil.copyfile(off.valid_store, store)
        before = md5(store)
        r = off.run(["--db", store, "--out", os.path.join(d, "o"), "--add-link", "0:1:0:5:0:0:1e9:0.1:0.1"])
        lines = reason(r.stderr)
        held = r.returncode == 1 and len(lines) == 1 and "outside [-pi, pi]" in lines[0] and md5(store) == before
        observed = "status %d: %s; store %s" % (r.returncode, " / ".join(lines) or "(no message)",
                                                 "unchanged" if md5(store) == before else "CHANGED")
        m.row(case, expected, observed, held)
    finally:
        m.done(d)


def case_names_and_links_offline(m, off):
    case = "offline_slam --db on a folder named '7', then --add-link of 1000 km with a 1 cm sigma"
    expected = ("status 0, the folder's session named './7' (a name of digits only would read as session 7's id); the "
                "link refused (status 1) in one line naming its bound; the store unchanged by the refusal")
    d = m.tempdir("names_links")
    try:
        shutil.copytree(off.folder("a"), os.path.join(d, "7"))
        store = os.path.join(d, "s.db")
        r = subprocess.run(off.cmd(["--session", "7", "--out", os.path.join(d, "o"), "--db", store]), cwd=d,
                           capture_output=True, text=True, timeout=180)
        con = ro_connect(store)
        try:
            names = [n for (n,) in con.execute("SELECT name FROM sessions ORDER BY id")]
        finally:
            con.close()
        before = md5(store)
        link = off.run(["--db", store, "--out", os.path.join(d, "o2"), "--add-link", "0:1:0:5:1e6:0:0:0.01:0.01"])
        lines = reason(link.stderr)
        held = (r.returncode == 0 and names == ["./7"] and link.returncode == 1 and len(lines) == 1
                and "at most" in lines[0] and md5(store) == before)
        observed = "run: status %d, sessions %s; --add-link: status %d: %s; store %s" % (
            r.returncode, names, link.returncode, " / ".join(lines) or "(no message)",
            "unchanged" if md5(store) == before else "CHANGED")
        m.row(case, expected, observed, held)
    finally:
        m.done(d)


def bad_store_case(m, off, label, make, expect_refusal=True, expected=None):
    case = "store: " + label
    expected = expected or "refused: one line naming the file; the file byte-identical"
    d = m.tempdir("store")
    try:
        store = make(d)
        is_file = os.path.isfile(store)
        before = md5(store) if is_file else sorted(os.listdir(store)) if os.path.isdir(store) else None
        r = off.run(["--session", off.folder("b"), "--out", os.path.join(d, "out"), "--db", store])
        after = md5(store) if is_file else sorted(os.listdir(store)) if os.path.isdir(store) else None
        lines = reason(r.stderr)
        crashed = r.returncode < 0 or r.returncode > 2
        if expect_refusal:
            held = (r.returncode in (1, 2) and len(lines) == 1 and store in lines[0] and before == after)
            observed = "status %d: %s; %s" % (r.returncode, " / ".join(lines) or "(no message)",
                                               "unchanged" if before == after else "CHANGED")
        else:
            held, observed = expect_refusal_free(r, store, lines, crashed)
        m.row(case, expected, observed, held)
    finally:
        m.done(d)


def expect_refusal_free(r, store, lines, crashed):
    if crashed:
        return False, "crashed (status %d): %s" % (r.returncode, " / ".join(lines[-2:]))
    if r.returncode != 0:
        return False, "status %d: %s" % (r.returncode, " / ".join(lines))
    dmode = oct(os.stat(os.path.dirname(store)).st_mode & 0o777)
    fmode = oct(os.stat(store).st_mode & 0o777)
    return (dmode == "0o700" and fmode == "0o600" and integrity(store) == "ok"), \
        "status 0; directory created %s, store %s, %s keyframes, integrity %s" % (dmode, fmode, keyframe_count(store),
                                                                                integrity(store))


def offline_store_cases(m, off):
    def truncated(d):
        p = os.path.join(d, "s.db")
        with open(off.valid_store, "rb") as f:
            data = f.read()
        with open(p, "wb") as f:
            f.write(data[: len(data) // 2])
        return p

    def random_bytes(d):
        p = os.path.join(d, "s.db")
        with open(p, "wb") as f:
            f.write(random.Random(21).randbytes(1 << 20))
        return p

    def foreign(d):
        p = os.path.join(d, "s.db")
        con = sqlite3.connect(p)
        con.execute("CREATE TABLE customers (id INTEGER PRIMARY KEY, name TEXT)")
        con.execute("INSERT INTO customers (name) VALUES ('x')")
        con.commit()
        con.close()
        return p

    def directory(d):
        p = os.path.join(d, "s.db")
        os.mkdir(p)
        return p

    def missing_dir(d):
        return os.path.join(d, "no", "such", "dir", "s.db")

    def read_only(d):
        p = os.path.join(d, "s.db")
        shutil.copyfile(off.valid_store, p)
        os.chmod(p, 0o444)
        return p

    bad_store_case(m, off, "valid store cut in half", truncated)
    bad_store_case(m, off, "1 MiB of random bytes", random_bytes)
    bad_store_case(m, off, "foreign schema (another SQLite database)", foreign)
    bad_store_case(m, off, "a directory as the store path", directory)
    bad_store_case(m, off, "in a missing directory", missing_dir, expect_refusal=False,
                   expected="README: the directory created 0700, the store 0600; the run succeeds")
    bad_store_case(m, off, "read-only file (chmod 444, run as %s)" % ("root" if os.geteuid() == 0 else "a user"),
                   read_only)


def dataset_case(m, off, label, mutate, expected, judge):
    case = "dataset: " + label
    d = m.tempdir("dataset")
    try:
        folder = os.path.join(d, "a")
        shutil.copytree(off.folder("a"), folder)
        mutate(folder)
        r = off.run(["--session", folder, "--out", os.path.join(d, "out")], quiet=False)
        out = os.path.join(d, "out")
        held, observed = judge(r, out)
        m.row(case, expected, observed, held)
    finally:
        m.done(d)


def read_frames(folder):
    with open(os.path.join(folder, "frames.csv")) as f:
        lines = f.read().splitlines()
    return lines[0], [line.split(",") for line in lines[1:] if line]


def write_frames(folder, header, rows):
    with open(os.path.join(folder, "frames.csv"), "w") as f:
        f.write(header + "\n" + "".join(",".join(r) + "\n" for r in rows))


def offline_dataset_cases(m, off):
    def summary(r):
        return " / ".join(line for line in r.stdout.splitlines() if line.startswith("session ")) or short(r.stdout, 120)

    def pieces(out):
        p = os.path.join(out, "pieces.csv")
        if not os.path.exists(p):
            return "no pieces.csv"
        with open(p) as f:
            return "%d pieces" % (len(f.read().splitlines()) - 1)

    def counted(*marks):
        """Exit 0 with one of marks in the summary (the fault counted), or a one-line refusal (1 or 2)."""
        return lambda r, out: clear(r, out, marks)

    def clear(r, out, marks):
        lines = reason(r.stderr)
        if r.returncode == 0:
            seen = summary(r) + "; " + pieces(out)
            return any(k in seen for k in marks), "status 0; %s" % seen
        if r.returncode in (1, 2) and len(lines) == 1:
            return True, "status %d: %s" % (r.returncode, lines[0])
        return False, "status %d: %s" % (r.returncode, " / ".join(lines[-3:]) or "(no message)")

    def corrupt_image(folder):
        _, rows = read_frames(folder)
        with open(os.path.join(folder, rows[len(rows) // 2][1]), "wb") as f:
            f.write(random.Random(3).randbytes(5000))

    def one_skip(r, out):
        held = r.returncode == 0 and "1 skipped (1 image" in r.stdout
        return held, "status %d; %s" % (r.returncode, summary(r) if r.returncode == 0 else " / ".join(reason(r.stderr)))

    dataset_case(m, off, "a corrupt image file", corrupt_image, "a counted skip (1 image), exit 0", one_skip)

    def altitude(value):
        def mutate(folder):
            header, rows = read_frames(folder)
            rows[len(rows) // 2][3] = value
            write_frames(folder, header, rows)
        return mutate

    expected = ("README Bad input: the frame skipped or given the last valid altitude (counted), exit 0; "
                "or a one-line refusal naming frames.csv; no crash")
    for label, value in [("NaN", "nan"), ("inf", "inf"), ("negative", "-2.0"), ("empty", "")]:
        dataset_case(m, off, "frames.csv altitude %s" % label, altitude(value), expected,
                     counted("1 skipped (0 image, 1 altitude)", " 1 altitudes reused"))
    # Positive but absurd (a glitch, a sensor's "no bottom" value): above odometry.max_altitude_m.
    dataset_case(m, off, "frames.csv altitude 1e308", altitude("1e308"),
                 "the frame given the last valid altitude, counted above odometry.max_altitude_m, exit 0",
                 counted(" 1 altitudes reused (1 above odometry.max_altitude_m)"))

    def backwards(folder):
        header, rows = read_frames(folder)
        i = len(rows) // 2
        rows[i][2] = "%.6f" % (float(rows[i - 1][2]) - 5.0)
        write_frames(folder, header, rows)

    def day_jump(folder):
        header, rows = read_frames(folder)
        for r in rows[len(rows) // 2:]:
            r[2] = "%.6f" % (float(r[2]) + 86400.0)
        write_frames(folder, header, rows)

    def refused(*words):
        """Refused (status 1) in one line holding every word, before anything is written."""
        def judge(r, out):
            lines = reason(r.stderr)
            held = (r.returncode == 1 and len(lines) == 1 and all(w in lines[0] for w in words)
                    and not os.path.exists(out))
            return held, "status %d: %s%s" % (r.returncode, " / ".join(lines[-2:]) or summary(r),
                                               "" if not os.path.exists(out) else "; outputs written")
        return judge

    def entry(value, make=None):
        """frames.csv's middle entry set to `value` (None: kept), after make(folder, entry) made what it names."""
        def mutate(folder):
            header, rows = read_frames(folder)
            row = rows[len(rows) // 2]
            if make:
                make(folder, row[1])
            if value is not None:
                row[1] = value(folder) if callable(value) else value
            write_frames(folder, header, rows)
        return mutate

    def outside_image(folder):  # a real image of the mission, outside this folder
        path = os.path.join(os.path.dirname(folder), "outside.jpg")
        shutil.copyfile(os.path.join(off.folder("b"), read_frames(off.folder("b"))[1][0][1]), path)
        return path

    def link_out(folder, name):
        os.remove(os.path.join(folder, name))
        os.symlink(outside_image(folder), os.path.join(folder, name))

    leave = "refused (status 1) in one line naming frames.csv and the entry, which leaves the folder; nothing written"
    dataset_case(m, off, "frames.csv entry ../../etc/passwd", entry("../../etc/passwd"), leave,
                 refused("frames.csv:", "'../../etc/passwd' climbs above the folder"))
    dataset_case(m, off, "frames.csv entry the absolute path of a real image outside the folder", entry(outside_image),
                 leave, refused("frames.csv:", "outside.jpg' is an absolute path"))
    dataset_case(m, off, "an image symlinked to a real image outside the folder", entry(None, link_out), leave,
                 refused("frames.csv: image '", "resolves to", "outside.jpg, outside the folder"))
    dataset_case(m, off, "an image entry that is a directory",
                 entry("adir", lambda folder, name: os.mkdir(os.path.join(folder, "adir"))),
                 "refused (status 1) in one line saying the entry is a directory; nothing written",
                 refused("image 'adir' of frame", "is a directory, not an image file"))
    dataset_case(m, off, "an image entry that is a FIFO",
                 entry("pipe.jpg", lambda folder, name: os.mkfifo(os.path.join(folder, "pipe.jpg"))),
                 "refused (status 1) at once in one line saying the entry is a FIFO (never opened); nothing written",
                 refused("image 'pipe.jpg' of frame", "is a FIFO (named pipe), not an image file"))

    def camera_doubled(folder):
        path = os.path.join(folder, "camera.yaml")
        with open(path) as f:
            values = dict(line.split(":", 1) for line in f.read().splitlines() if ":" in line)
        with open(path, "w") as f:
            f.write("".join("%s: %g\n" % (k.strip(), 2 * float(v)) for k, v in values.items()))

    dataset_case(m, off, "camera.yaml of twice the images' size", camera_doubled,
                 "refused (status 1) before the run in one line naming camera.yaml and both sizes (every frame would "
                 "be skipped); nothing written",
                 refused("camera.yaml: a camera of", "px, but the images are", "every frame would be skipped"))

    dataset_case(m, off, "stamps going backwards (one frame 5 s back)", backwards,
                 "README Bad input: skipped (counted) or a new session; or a one-line refusal; no crash",
                 counted("1 skipped (1 image", "2 pieces"))
    dataset_case(m, off, "stamps jumping a day forward (second half)", day_jump,
                 "README Bad input: a new session (2 pieces); or a one-line refusal; no crash", counted("2 pieces"))


NAV_JUMP_SURVEY = """
seed: 5
world: {width_m: 12, height_m: 10, featureless_fraction: 0}
sessions:
  - name: a
    mission: {pattern: loop, start_m: [3.5, 2.5], length_m: 4.0, width_m: 3.0, laps: 1.0,
              speed_m_s: 0.4, frame_period_s: 1.0, altitude_m: 2.0}
    water:
      stretches:
        - {first_frame: 8, num_frames: 12, kind: blank}
    nav: {enabled: true}
"""


def case_nav_jump_offline(m, off):
    """A nav that jumps 1 km where vision goes blank and stays there: each jumped reading is refused
    (nav_implausible), the blank ends the piece, and the next piece must not be placed by the jumped
    reading (it was placed 1 km off)."""
    case = "offline: the nav jumps 1 km east at a black-out (frames 8..19 blank) and stays there"
    expected = ("the jumped readings refused (nav steps too fast); the piece after the tracking loss not placed "
                "by the nav (a line says why): every pose within the 12 x 10 m survey, none 1 km off; exit 0")
    d = m.tempdir("nav_jump")
    try:
        with open(os.path.join(d, "survey.yaml"), "w") as f:
            f.write(NAV_JUMP_SURVEY)
        r = subprocess.run([os.path.join(off.bin, "make_survey"), "--config", os.path.join(d, "survey.yaml"), "--out",
                            os.path.join(d, "m"), "--no-bag", "--quiet"], capture_output=True, text=True, timeout=120)
        if r.returncode != 0:
            return m.row(case, expected, "make_survey failed: " + short(r.stderr), False)
        folder = os.path.join(d, "m", "a")
        nav = os.path.join(folder, "nav.csv")
        with open(nav) as f:
            lines = f.read().splitlines()
        _, frames = read_frames(folder)
        jump_at = float(frames[8][2])
        rows = [lines[0]]
        for line in lines[1:]:
            c = line.split(",")
            if float(c[0]) >= jump_at - 1e-9:
                c[1] = "%.6f" % (float(c[1]) + 1000.0)
            rows.append(",".join(c))
        with open(nav, "w") as f:
            f.write("\n".join(rows) + "\n")
        out = os.path.join(d, "out")
        r = off.run(["--session", folder, "--out", out], quiet=False)
        farthest = float("inf")
        if r.returncode == 0:
            with open(os.path.join(out, "trajectory.csv")) as f:
                farthest = max(math.hypot(float(row["x_m"]), float(row["y_m"])) for row in csv.DictReader(f))
        # The placer's sentences, not the stream's closing count ("... so far: ..., N placed by the nav").
        lines = r.stdout.splitlines()
        said = [line for line in lines if "placed by the nav" in line and " so far: " not in line]
        counted = [line for line in lines if " so far: " in line]
        too_fast = re.search(r"(\d+) nav steps too fast", r.stdout)
        held = (r.returncode == 0 and "tracking resumed" in r.stdout and farthest < 20.0 and len(said) == 1
                and "not placed by the nav after the tracking loss: nav step" in said[0]
                and all(line.endswith(", 0 placed by the nav") for line in counted)
                and too_fast is not None and int(too_fast.group(1)) > 0)
        observed = "status %d; %s nav steps refused; the farthest pose %.1f m from the map's origin; %s" % (
            r.returncode, too_fast.group(1) if too_fast else "no", farthest,
            " / ".join(said) or "no placement said" if r.returncode == 0 else " / ".join(reason(r.stderr)))
        m.row(case, expected, observed, held)
    finally:
        m.done(d)


OFFLINE_CASES = [case_kill_offline, case_two_writers, case_hard_link_writer, case_export_planted_links,
                 case_evaluate_planted_links,
                 case_self_merge_hard_link, case_restart_ids, case_index_steps, case_add_link_yaw_offline,
                 case_names_and_links_offline, offline_store_cases, offline_dataset_cases, case_nav_jump_offline]


# Each in a process of its own (rospy talks to one master per process): fault_matrix_live.py.
LIVE_CASES = [("service_misuse", 240), ("concurrent", 240), ("kill_manager", 240), ("bad_images", 240),
              ("kill_manager_moments", 240), ("replay_rates", 240), ("silent_altitude", 240), ("burst", 240),
              ("store_cap", 240), ("export_links", 240), ("bounds_and_paths", 240), ("quoted_datum", 240),
              ("dvl_relay", 240), ("ids_and_inputs", 240),
              ("nav_clock_and_mount", 240)]


def live_case(name, timeout):
    def run(m, off):
        d = m.tempdir("live_" + name)
        proc = subprocess.Popen(["/usr/bin/python3", os.path.join(HERE, "fault_matrix_live.py"), name, "--survey",
                                 off.survey, "--dir", d], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                start_new_session=True)
        err_note = ""
        try:
            try:
                out, err = proc.communicate(timeout=timeout)
            except subprocess.TimeoutExpired:
                err_note = "timed out after %d s; " % timeout
                raise
        except BaseException:  # a timeout, Ctrl-C, SIGTERM: SIGINT makes the case stop what it started
            os.killpg(proc.pid, signal.SIGINT)
            try:
                out, err = proc.communicate(timeout=60)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                out, err = proc.communicate()
            if not err_note:
                m.done(d)
                raise
        err = err_note + err
        rows = [json.loads(line[4:]) for line in out.splitlines() if line.startswith("ROW ")]
        for r in rows:
            m.row(*r)
        if not rows:
            tail = [line for line in err.splitlines() if line.strip()][-2:]
            m.row("live: " + name, "runs to its verdict", "no verdict (status %s): %s" % (proc.returncode, " / ".join(tail)),
                  False)
        m.done(d)
    run.__name__ = "live_" + name
    return run


def junit(path, rows, seconds):
    failures = sum(1 for r in rows if not r[3])
    parts = ['<?xml version="1.0" encoding="utf-8"?>\n',
             '<testsuite name="fault_matrix" tests="%d" failures="%d" errors="0" skipped="0" time="%.1f">\n' %
             (len(rows), failures, seconds)]
    for case, expected, observed, held, _ in rows:
        parts.append('  <testcase classname="fault_matrix" name=%s>\n' % xml.sax.saxutils.quoteattr(case))
        if not held:
            parts.append('    <failure message=%s/>\n' % xml.sax.saxutils.quoteattr("expected: %s; observed: %s" %
                                                                                   (expected, observed)))
        parts.append("  </testcase>\n")
    parts.append("</testsuite>\n")
    write_atomically(path, "".join(parts))


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--bin-dir", default=os.environ.get("UWMS_BIN_DIR", ""), help="offline_slam's directory")
    p.add_argument("--only", action="append", default=[], help="run the case groups whose name contains this")
    p.add_argument("--offline", action="store_true", help="offline cases only (no ROS)")
    p.add_argument("--junit", help="also write the result as JUnit XML")
    p.add_argument("--keep", action="store_true", help="leave the temporary directories")
    a = p.parse_args()
    if not a.bin_dir or not os.path.exists(os.path.join(a.bin_dir, "offline_slam")):
        p.error("offline_slam not found: give --bin-dir or UWMS_BIN_DIR (fault_matrix.sh sets it)")
    started = time.monotonic()
    m = Matrix(a.keep)
    base = tempfile.mkdtemp(prefix="uwms_fault_survey.")
    print("| case | expected | observed | verdict |\n| --- | --- | --- | --- |", flush=True)
    try:
        try:
            off = Offline(a.bin_dir, base)
        except Exception as e:  # no survey, no case: a row that failed, and the summary line
            m.row("setup (make_survey, a reference store)", "succeeds", short(str(e), 300), False)
            groups = []
        else:
            groups = list(OFFLINE_CASES)
        if not a.offline and groups:
            groups += [live_case(name, timeout) for name, timeout in LIVE_CASES]
        for group in groups:
            if a.only and not any(s in group.__name__ for s in a.only):
                continue
            t0 = time.monotonic()
            try:
                group(m, off)
            except Exception as e:  # a case that breaks is a row that failed, and the others still run
                traceback.print_exc()
                m.row(group.__name__, "runs to its verdict", "the case itself failed: %s" % short(repr(e)), False)
            print("[fault_matrix] %s: %.1f s" % (group.__name__, time.monotonic() - t0), file=sys.stderr, flush=True)
    finally:
        m.done(base)
    held = sum(1 for r in m.rows if r[3])
    seconds = time.monotonic() - started
    print("\n%d of %d held" % (held, len(m.rows)))
    print("[fault_matrix] %.0f s in all" % seconds, file=sys.stderr)
    if a.junit:
        junit(a.junit, m.rows, seconds)
    return 0 if held == len(m.rows) and m.rows else 1


def on_term(signum, frame):
    raise KeyboardInterrupt("SIGTERM")  # the same clean-up as Ctrl-C


if __name__ == "__main__":
    signal.signal(signal.SIGTERM, on_term)
    sys.exit(main())
