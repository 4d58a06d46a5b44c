"""Smoke test of the install space (catkin_make install), run by scripts/test.sh with only
<workspace>/install/setup.bash sourced: nothing of the devel space or the source tree on any path.

- the package, its messages and its nodelet plugins resolve to the install space;
- every launch file parses, and every file it pulls in lies in the install space (or the system);
- slam.launch loads the three nodelets into a manager (and, standalone, the three nodes) and each
  advertises its topics (awaited on the master, no fixed sleep);
- every tool CMakeLists.txt builds is installed and answers --help with exit status 0 via rosrun.

Environment: UWMS_INSTALL, the install prefix (<workspace>/install).
"""
import os
import re
import signal
import socket
import subprocess
import time
import xmlrpc.client

import pytest

PKG = "uw_multislam"
REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.realpath(__file__))))
INSTALL = os.path.realpath(os.environ.get("UWMS_INSTALL", ""))
SHARE = os.path.join(INSTALL, "share", PKG)
LIBEXEC = os.path.join(INSTALL, "lib", PKG)
# Launch files and the arguments each needs (the same as the roslaunch checks of CMakeLists.txt).
LAUNCH = {"core.launch": [], "slam.launch": [], "onboard.launch": ["fixed_altitude:=2.5"],
          "replay.launch": ["bag:=mission.bag", "rviz:=true"], "demo.launch": ["bag:=mission.bag"]}
# What each nodelet advertises as soon as it is loaded (include/uw_multislam/ros/topics.h).
ADVERTISED = {
    "Odometry": ["/uw_multislam/keyframes", "/uw_multislam/odometry/pose"],
    "LoopDetector": ["/uw_multislam/loops", "/uw_multislam/keyframe_hashes"],
    "Backend": ["/uw_multislam/session_trajectory", "/uw_multislam/active_session"],
}
SERVICES = ["/uw_multislam/list_sessions", "/uw_multislam/join_sessions"]


def run(*cmd, timeout=60, **kw):
    return subprocess.run(list(cmd), capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL, **kw)


def in_install(path):
    return os.path.realpath(path).startswith(INSTALL + os.sep)


def built_tools():
    """Executables CMakeLists.txt builds from src/tools and src/nodes, and the Python tools it installs."""
    with open(os.path.join(REPO, "CMakeLists.txt")) as f:
        text = re.sub(r"#[^\n]*", "", f.read())
    tools = set(re.findall(r"add_executable\((\w+) src/tools/", text))
    nodes = set(re.findall(r"add_executable\((\w+) src/nodes/", text))
    m = re.search(r"catkin_install_python\(PROGRAMS ([^)]*?) DESTINATION", text)
    tools |= {os.path.basename(p) for p in m.group(1).split()} if m else set()
    return tools, nodes


def test_only_the_install_space_is_sourced():
    assert INSTALL and os.path.isfile(os.path.join(INSTALL, "setup.bash")), "UWMS_INSTALL=%r" % INSTALL
    for var in ("ROS_PACKAGE_PATH", "CMAKE_PREFIX_PATH", "PYTHONPATH", "LD_LIBRARY_PATH"):
        for entry in filter(None, os.environ.get(var, "").split(":")):
            # REPO + os.sep: the default workspace <clone>_ws sits beside the clone and shares its prefix.
            inside_repo = entry == REPO or entry.startswith(REPO + os.sep)
            assert "devel" not in entry.split(os.sep) and not inside_repo, "%s has %s" % (var, entry)


def test_package_and_messages_resolve_to_the_install_space():
    found = run("rospack", "find", PKG)
    assert found.returncode == 0, found.stderr
    assert os.path.realpath(found.stdout.strip()) == os.path.realpath(SHARE)
    mod = run("/usr/bin/python3", "-c", "import uw_multislam.msg as m, uw_multislam.srv as s; "
              "print(m.__file__); print(s.ListSessions)")
    assert mod.returncode == 0, mod.stderr
    assert in_install(mod.stdout.splitlines()[0]), mod.stdout
    for header in ("Keyframe.h", "ListSessions.h", "core/session/session_manager.h"):
        assert os.path.isfile(os.path.join(INSTALL, "include", PKG, header)), header


def test_nodelet_plugins_are_listed_with_their_library():
    plugins = run("rospack", "plugins", "--attrib=plugin", "nodelet")
    assert plugins.returncode == 0, plugins.stderr
    ours = [line.split(" ", 1)[1] for line in plugins.stdout.splitlines() if line.split(" ")[0] == PKG]
    assert ours == [os.path.join(SHARE, "nodelet_plugins.xml")], plugins.stdout
    with open(ours[0]) as f:
        xml = f.read()
    assert set(re.findall(r'class name="uw_multislam/(\w+)"', xml)) == set(ADVERTISED)
    for lib in re.findall(r'<library path="([^"]+)"', xml):
        assert os.path.isfile(os.path.join(INSTALL, lib + ".so")), lib


def test_every_launch_file_is_installed_and_checked():
    installed = set(os.listdir(os.path.join(SHARE, "launch")))
    assert installed == set(os.listdir(os.path.join(REPO, "launch"))), installed
    assert installed == set(LAUNCH), "add the new launch file to LAUNCH: %s" % sorted(installed - set(LAUNCH))


@pytest.mark.parametrize("launch", sorted(LAUNCH))
def test_launch_file_parses_from_the_install_space(launch):
    nodes = run("roslaunch", "--nodes", PKG, launch, *LAUNCH[launch])
    assert nodes.returncode == 0, nodes.stdout + nodes.stderr
    assert nodes.stdout.split(), "no node in %s" % launch
    files = run("roslaunch", "--files", PKG, launch, *LAUNCH[launch])
    assert files.returncode == 0, files.stdout + files.stderr
    for path in files.stdout.split():
        assert in_install(path), "%s pulls in %s from outside the install space" % (launch, path)


@pytest.mark.parametrize("tool", sorted(built_tools()[0]))
def test_tool_answers_help(tool):
    assert os.access(os.path.join(LIBEXEC, tool), os.X_OK), "%s is built but not installed" % tool
    helped = run("rosrun", PKG, tool, "--help")
    assert helped.returncode == 0, helped.stdout + helped.stderr
    assert "usage" in helped.stdout.lower(), helped.stdout + helped.stderr


def test_the_python_tools_modules_are_installed_beside_them():
    """The modules CMakeLists.txt installs with install(FILES src/tools/*.py) (the tools import them from
    their own directory): present, and what an installed tool imports."""
    with open(os.path.join(REPO, "CMakeLists.txt")) as f:
        text = re.sub(r"#[^\n]*", "", f.read())
    modules = re.findall(r"install\(FILES ((?:src/tools/\w+\.py ?)+) DESTINATION", text)
    names = [os.path.basename(p)[:-3] for group in modules for p in group.split()]
    assert "atomic_file" in names, modules
    for name in names:
        found = run("/usr/bin/python3", "-c", "import sys; sys.path.insert(0, %r); import %s; print(%s.__file__)" % (
            LIBEXEC, name, name))
        assert found.returncode == 0 and in_install(found.stdout.strip()), found.stdout + found.stderr


def test_nodes_are_installed():
    for node in sorted(built_tools()[1]):
        assert os.access(os.path.join(LIBEXEC, node), os.X_OK), "%s is built but not installed" % node


def free_port():
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def await_graph(master_uri, topics, services, launch, timeout=60.0):
    """Polls the master until every topic has a publisher and every service is offered."""
    master = xmlrpc.client.ServerProxy(master_uri)
    deadline = time.monotonic() + timeout
    missing = set(topics) | set(services)
    while time.monotonic() < deadline and launch.poll() is None:
        try:
            _, _, (pubs, _, srvs) = master.getSystemState("/install_smoke")
            missing = (set(topics) - {t for t, _ in pubs}) | (set(services) - {s for s, _ in srvs})
        except OSError:  # the master is not up yet
            pass
        if not missing:
            return missing
        time.sleep(0.1)  # a polling interval, not a wait for the result
    return missing


@pytest.mark.parametrize("standalone", ["false", "true"])
def test_slam_launch_loads_the_nodelets_and_they_advertise(standalone, tmp_path):
    port = free_port()
    env = dict(os.environ, ROS_MASTER_URI="http://localhost:%d" % port, ROS_HOME=str(tmp_path))
    launch = subprocess.Popen(["roslaunch", "-p", str(port), PKG, "slam.launch", "store_path:=none",
                               "standalone:=" + standalone], env=env, stdin=subprocess.DEVNULL,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                              start_new_session=True)
    try:
        missing = await_graph(env["ROS_MASTER_URI"], sum(ADVERTISED.values(), []), SERVICES, launch)
    finally:
        if launch.poll() is None:
            os.killpg(launch.pid, signal.SIGINT)
        try:
            output = launch.communicate(timeout=30)[0]
        except subprocess.TimeoutExpired:
            os.killpg(launch.pid, signal.SIGKILL)
            output = launch.communicate()[0]
    assert not missing, "not advertised: %s\n%s" % (sorted(missing), output[-3000:])
    assert "Failed to load nodelet" not in output, output[-3000:]
