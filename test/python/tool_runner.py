"""Shared helpers of the tool tests: run a built uw_multislam binary, read a CSV.

The binaries come from UWMS_BIN_DIR (set by CMake to the devel space), or the default workspace
(<repo>_ws beside the repository, scripts/common.sh).
"""
import csv
import os
import subprocess
from pathlib import Path

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.realpath(__file__))))
BIN_DIR = os.environ.get("UWMS_BIN_DIR", os.path.join(REPO + "_ws", "devel", "lib", "uw_multislam"))
# rosbag::Bag loads its encryption plugins through rospack, which keeps a cache in ROS_HOME and
# warns on stderr when it cannot create it: ctest gives each suite a ROS_HOME that may not exist
# yet (a user's ~/.ros does), and the tools' tests count stderr's lines.
if os.environ.get("ROS_HOME"):
    os.makedirs(os.environ["ROS_HOME"], exist_ok=True)


# Two small dives over one seabed that overlap (make_survey YAML text; the fault matrix flies the same file).
TWO_DIVES = Path(REPO, "config", "missions", "two_dives.yaml").read_text()


def run_tool(tool, *args, timeout=300):
    """Runs BIN_DIR/tool with the arguments; returns the CompletedProcess (text output)."""
    return subprocess.run([os.path.join(BIN_DIR, tool), *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


def make_survey(base, spec):
    """Generates the survey of `spec` (make_survey YAML text as a str, or a YAML file as a Path)
    into base/m without bags; returns that folder (a failure fails the test with make_survey's error)."""
    base = Path(base)
    config = spec
    if isinstance(spec, str):
        config = base / "survey.yaml"
        config.write_text(spec)
    r = run_tool("make_survey", "--config", config, "--out", base / "m", "--no-bag", "--quiet")
    assert r.returncode == 0, r.stderr
    return base / "m"


def read_csv(path):
    with open(path) as f:
        return list(csv.DictReader(f))
