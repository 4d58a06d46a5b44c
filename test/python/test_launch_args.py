"""Every launch file's arguments, as `roslaunch --ros-args` shows them to a user:
each documented, and only the bags required. roslaunch lists an argument whose default is empty
as required, so the launch files use the words 'config' and 'none' for "leave it to the config"
and "nothing"; the second test checks that those words reach the parameters and commands as
nothing, by expanding the launch files the way roslaunch does."""
import os
import shlex
import subprocess

import pytest

LAUNCH = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "launch")
FILES = sorted(f for f in os.listdir(LAUNCH) if f.endswith(".launch"))
REQUIRED = {"demo.launch": ["bag"], "replay.launch": ["bag"]}


def ros_args(name):
    r = subprocess.run(["roslaunch", "--ros-args", os.path.join(LAUNCH, name)], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0, r.stderr
    return r.stdout


@pytest.mark.parametrize("name", FILES)
def test_every_argument_is_documented_and_only_the_bags_are_required(name):
    text = ros_args(name)
    assert "undocumented" not in text
    required = []
    if "Required Arguments:" in text:
        block = text.split("Required Arguments:", 1)[1].split("Optional Arguments:", 1)[0]
        required = [line.split(":", 1)[0].strip() for line in block.splitlines() if line.strip()]
    assert required == REQUIRED.get(name, []), text


def load(name, *args):
    import roslaunch.config
    import roslaunch.xmlloader
    loader = roslaunch.xmlloader.XmlLoader()
    config = roslaunch.config.ROSLaunchConfig()
    loader.load(os.path.join(LAUNCH, name), config, argv=list(args), verbose=False)
    return config


def test_the_dvl_relay_is_the_packages_with_the_expression_as_one_argument():
    """onboard.launch dvl:= starts scripts/dvl_altitude.py (one throttled error naming a wrong field;
    rostest dvl_relay_errors), each argument whole as roslaunch splits them (an expression with
    spaces, a frame)."""
    config = load("onboard.launch", "dvl:=/dvl/data", "dvl_altitude:=m.range * 0.5", "dvl_frame:=dvl_link")
    relay, = [n for n in config.nodes if n.name == "dvl_altitude"]
    assert (relay.namespace, relay.package, relay.type) == ("/uw_multislam/", "uw_multislam", "dvl_altitude.py")
    assert shlex.split(relay.args) == ["--input", "/dvl/data", "--expression", "m.range * 0.5", "--frame", "dvl_link"]
    config = load("onboard.launch", "dvl:=/auv/dvl", "ns:=auv2")
    relay, = [n for n in config.nodes if n.name == "dvl_altitude"]
    assert shlex.split(relay.args) == ["--input", "/auv/dvl", "--expression", "m.altitude", "--frame", "header"]
    odometry, = [n for n in config.nodes if n.name == "odometry_node"]
    assert ["altitude", "/auv2/dvl_altitude"] in odometry.remap_args  # the odometry reads the relay
    assert not [n for n in load("onboard.launch").nodes if n.name == "dvl_altitude"]  # dvl:=none


def test_the_default_words_expand_to_nothing():
    """slam.launch with the defaults sets none of the five config-backed parameters and gives the
    manager no prefix; with values it sets them; replay.launch passes no play_args by default."""
    keys = ("backend_node/store_path", "odometry_node/image_transport", "odometry_node/camera_info_url",
            "odometry_node/rectified_images", "backend_node/mode")
    config = load("slam.launch")
    set_here = [k for k in config.params if k.startswith("/uw_multislam/") and k.endswith(keys)]
    # config/default.yaml (loaded by core.launch with rosparam) sets some of them: values from it only.
    for key in set_here:
        assert str(config.params[key].value) not in ("config", "none"), key
    manager, = [n for n in config.nodes if n.name == "manager"]
    assert manager.launch_prefix in (None, "")
    given = load("slam.launch", "store_path:=/tmp/s.db", "transport:=compressed", "camera_info_url:=file:///c.yaml",
                 "rectified_images:=true", "launch_prefix:=nice", "mode:=localisation")
    values = {k.rsplit("/uw_multislam/", 1)[1]: p.value for k, p in given.params.items() if k.startswith("/uw_multislam/")}
    assert [values[k] for k in keys] == ["/tmp/s.db", "compressed", "file:///c.yaml", True, "localisation"]
    assert [n for n in given.nodes if n.name == "manager"][0].launch_prefix == "nice"
    none = load("slam.launch", "store_path:=none")
    assert none.params["/uw_multislam/backend_node/store_path"].value == ""
    player, = [n for n in load("replay.launch", "bag:=/tmp/a.bag").nodes if n.type == "play"]
    assert player.args.split()[-1] == "/tmp/a.bag"  # nothing after the bag
    player, = [n for n in load("replay.launch", "bag:=/tmp/a.bag", "play_args:=-q").nodes if n.type == "play"]
    assert player.args.split()[-2:] == ["/tmp/a.bag", "-q"]
