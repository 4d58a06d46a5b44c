"""Every C++ tool reads its command line the same way (src/tools/cli.h, boost::program_options):

- --help / -h: the usage text on stdout, exit status 0;
- an unknown option, an abbreviated one, an option without its value, an option of one value given twice:
  one line "<tool>: <reason> (see --help)" on stderr, exit status 2, and nothing done;
- a flag given twice means the same as once; --name=value means --name value.

The tools are the executables CMakeLists.txt builds from src/tools, so a new tool is checked too.
"""
import os
import re

import pytest
from tool_runner import run_tool as run

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.realpath(__file__))))


def cpp_tools():
    with open(os.path.join(REPO, "CMakeLists.txt")) as f:
        return sorted(set(re.findall(r"add_executable\((\w+) src/tools/", f.read())))


# An option of one value each tool has, and a flag (None: the tool has none).
OPTIONS = {
    "baseline_odometry": ("--out", None),
    "bench_backend": ("--mission", "--robustness"),
    "bench_export": ("--from", None),
    "bench_loops": ("--posidonia", None),
    "bench_scale": ("--dir", "--keep"),
    "bench_store": ("--dir", "--no-images"),
    "export_survey": ("--out", "--quiet"),
    "folder_to_bag": ("--gt-topic", "--no-nav"),
    "loop_audit": ("--csv", "--verify-only"),
    "make_survey": ("--out", "--quiet"),
    "merge_stores": ("--config", "--quiet"),
    "offline_slam": ("--out", "--quiet"),
}


def test_every_tool_is_listed():
    assert cpp_tools() == sorted(OPTIONS)


def refused(r, tool, reason):
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    assert r.stderr == "%s: %s (see --help)\n" % (tool, reason), r.stderr
    assert r.stdout == "", r.stdout


@pytest.mark.parametrize("tool", sorted(OPTIONS))
def test_help_and_refusals_are_the_same_in_every_tool(tool, tmp_path):
    value, _ = OPTIONS[tool]
    for ask in ("--help", "-h"):
        r = run(tool, ask)
        assert r.returncode == 0 and r.stdout.startswith("usage: %s " % tool) and r.stderr == "", (ask, r)
    refused(run(tool, "--bogus"), tool, "unknown argument '--bogus'")
    refused(run(tool, value[:4]), tool, "unknown argument '%s'" % value[:4])  # no guessing the rest of a name
    refused(run(tool, value), tool, "%s needs a value" % value)
    refused(run(tool, value, tmp_path / "a", value, tmp_path / "b"), tool, "%s given more than once" % value)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("tool", sorted(t for t, (_, f) in OPTIONS.items() if f))
def test_a_flag_takes_no_value(tool):
    flag = OPTIONS[tool][1]
    refused(run(tool, flag + "=1"), tool, "%s takes no value" % flag)


def test_a_repeated_flag_and_name_equals_value():
    once = run("make_survey", "--preset", "hazy", "--dump-config")
    assert once.returncode == 0 and once.stdout != run("make_survey", "--dump-config").stdout, once.stderr
    twice = run("make_survey", "--preset=hazy", "--dump-config", "--dump-config")
    assert twice.returncode == 0 and twice.stdout == once.stdout, twice.stderr
    presets = run("make_survey", "--list-presets", "--list-presets")
    assert presets.returncode == 0 and "hazy" in presets.stdout.split(), presets.stderr


def test_an_argument_a_tool_does_not_take_is_refused():
    refused(run("offline_slam", "stray", "--dump-config"), "offline_slam", "unknown argument 'stray'")


def test_a_value_may_start_with_a_dash(tmp_path):
    """Southern latitudes and western longitudes: --origin -33.9,-151.2,0 is a value, not an option."""
    r = run("export_survey", "--db", tmp_path / "none.db", "--out", tmp_path / "o", "--origin", "-33.9,-151.2,0")
    assert r.returncode == 1 and "none.db" in r.stderr, r.stderr  # past the command line, to the missing store
