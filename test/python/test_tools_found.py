"""The Python tools are found and answer --help.

- rosrun finds exactly one of each (a workspace inside the repository made it find 9 copies, loop
  through the workspace's link back, and stop at a menu or `exec: : not found`); run the way a user
  does, in the environment of the workspace under test, with no terminal to answer a menu;
- the default workspace of the scripts lies outside the repository;
- --help works with no workspace sourced (no ROS_*, no PYTHONPATH), and a command without it
  says what to source instead of a traceback.
"""
import os
import subprocess

import pytest

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.realpath(__file__))))
TOOLS = ["sessions.py", "record_run.py", "evaluate.py", "season.py"]
ROS_TOOLS = {"sessions.py": ["list"], "record_run.py": ["--out", "/nonexistent/never_written"]}
BARE_ENV = {"PATH": "/usr/bin:/bin", "LANG": "C.UTF-8"}


@pytest.mark.parametrize("tool", TOOLS)
def test_rosrun_finds_one(tool):
    assert os.environ.get("ROS_PACKAGE_PATH"), "needs a sourced workspace (catkin's run_tests has one)"
    run = subprocess.run(["rosrun", "uw_multislam", tool, "--help"], stdin=subprocess.DEVNULL,
                         capture_output=True, text=True, timeout=60)
    output = run.stdout + run.stderr
    assert "non-unique" not in output, output
    assert "File system loop" not in output, output
    assert run.returncode == 0, output
    assert run.stdout.startswith("usage: %s" % tool), output


def test_default_workspace_is_outside_the_repository():
    env = {k: v for k, v in os.environ.items() if k != "UWMS_WS"}
    ws = subprocess.run(["bash", "-c", 'source "$1/scripts/common.sh" && echo "$UWMS_WS"', "-", REPO], env=env,
                        capture_output=True, text=True, check=True).stdout.strip()
    ws = os.path.realpath(ws)
    assert ws != REPO and not ws.startswith(REPO + os.sep), "%s is inside %s" % (ws, REPO)


@pytest.mark.parametrize("tool", TOOLS)
def test_help_without_a_sourced_workspace(tool):
    run = subprocess.run(["/usr/bin/python3", os.path.join(REPO, "src", "tools", tool), "--help"], env=BARE_ENV,
                         stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    assert run.stdout.startswith("usage: %s" % tool), run.stdout + run.stderr


@pytest.mark.parametrize("tool", sorted(ROS_TOOLS))
def test_command_without_a_sourced_workspace_says_what_to_source(tool):
    run = subprocess.run(["/usr/bin/python3", os.path.join(REPO, "src", "tools", tool), *ROS_TOOLS[tool]],
                         env=BARE_ENV, stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=60)
    assert run.returncode == 1, run.stdout + run.stderr
    assert "Traceback" not in run.stderr, run.stderr
    assert "setup.bash" in run.stderr, run.stderr
