"""sessions.py without a ROS master: the argument checks of every command (reload included) and
the error when nothing answers. The answers of a live back-end are checked by
test/rostest/check_backend.py (test_3), which runs the tool against it."""
import os
import socket
import subprocess
import sys

import pytest

TOOL = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "src", "tools", "sessions.py")


def closed_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run(*args):
    env = dict(os.environ, ROS_MASTER_URI="http://127.0.0.1:%d" % closed_port())
    return subprocess.run([sys.executable, TOOL, *args], capture_output=True, text=True, timeout=60, env=env)


@pytest.mark.parametrize("args, why", [
    (["reload"], "reload takes 1 argument(s), got 0"),
    (["reload", "a", "b"], "reload takes 1 argument(s), got 2"),
    (["split", "1", "2"], "split takes 1 argument(s), got 2"),
    (["join", "0"], "join takes 2 to 3 argument(s), got 1"),
    (["list", "x"], "list takes 0 argument(s), got 1"),
    (["start", "a", "b"], "start takes 0 to 1 argument(s), got 2"),
    (["join", "0", "one"], "join: wrong arguments"),
    (["rename", "0"], "invalid choice: 'rename'"),
    (["pause", "now"], "pause takes 0 argument(s), got 1"),
    (["resume", "1"], "resume takes 0 argument(s), got 1"),
    (["finish", "0"], "finish takes 0 argument(s), got 1"),
    (["optimise", "0"], "optimise takes 0 argument(s), got 1"),
    (["link", "0", "1", "1", "1", "0", "1", "0", "0.1"], "link takes 9 to 10 argument(s), got 8"),
    (["link", "0", "1", "1", "one", "0", "1", "0", "0.1", "0.01"], "link: wrong arguments"),
    (["link", "0", "1", "1", "1", "0", "1", "0", "0", "0.01"], "link: wrong arguments"),  # sigma 0
    (["detect", "0"], "detect takes 2 to 1000 argument(s), got 1"),
    (["detect", "0", "x"], "detect: wrong arguments"),
    (["mode"], "mode takes 1 argument(s), got 0"),
    (["find", "0", "1", "1"], "find takes 4 argument(s), got 3"),
    (["find", "0", "1", "1", "x"], "find: wrong arguments"),
    (["unload"], "unload takes 1 argument(s), got 0"),
    (["delete"], "delete takes 1 to 2 argument(s), got 0"),
    (["delete", "0", "yes"], "delete: wrong arguments"),
    (["history", "1", "2"], "history takes 0 to 1 argument(s), got 2"),
    (["history", "all"], "history: wrong arguments"),
])
def test_wrong_arguments_exit_2_with_the_reason(args, why):
    res = run(*args)
    assert res.returncode == 2, res
    assert why in res.stderr
    assert res.stdout == ""


@pytest.mark.parametrize("args", [["reload", "yesterday"], ["list"], ["join", "0", "1"], ["pause"], ["resume"], ["finish"],
                                  ["optimise"], ["link", "0", "1", "1", "1", "0", "1", "0", "0.1", "0.01"],
                                  ["detect", "0", "1"], ["mode", "localisation"], ["history"],
                                  ["unload", "0"], ["delete", "0", "confirm"]])
def test_no_master_exits_1_naming_it(args):
    res = run("--timeout", "1", *args)
    assert res.returncode == 1, res
    assert "sessions.py %s: no ROS master at http://127.0.0.1:" % args[0] in res.stderr
    assert "Traceback" not in res.stderr


def test_help_lists_reload():
    res = run("--help")
    assert res.returncode == 0
    assert "reload" in res.stdout
