"""The rviz layout and the ways the package opens it.

rviz/uw_multislam.rviz names its topics relative, as the pipeline's are (include/uw_multislam/
ros/topics.h): rviz must run in the pipeline's namespace, /uw_multislam by default, or it
subscribes to /trajectory_markers and the like and shows nothing. Checked: every rviz command the
docs give (each resolved as rospy would resolve the namespace: ROS_NAMESPACE=, __ns:=), every rviz
node of the launch files, and that each of the layout's topics is one the pipeline publishes; and
that the layout shows the back-end's status (the status_marker text beside the vehicle)."""
import glob
import os
import re
import shlex
import xml.etree.ElementTree as ElementTree

import yaml

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
LAYOUT = os.path.join(ROOT, "rviz", "uw_multislam.rviz")
TOPICS_H = os.path.join(ROOT, "include", "uw_multislam", "ros", "topics.h")
NS = "/uw_multislam"  # the launch files' default ns


def topics_h():
    """kName -> "relative/name" of topics.h's topics (not the services, not the frame prefix)."""
    with open(TOPICS_H) as f:
        text = f.read().split("namespace frames", 1)[0]
    return {k: v for k, v in re.findall(r'constexpr char (k\w+)\[\] = "([^"]*)"', text)
            if not k.endswith("Service") and k != "kDefaultSessionFramePrefix"}


def displays():
    with open(LAYOUT) as f:
        layout = yaml.safe_load(f)
    return layout["Visualization Manager"]["Displays"]


def layout_topics():
    return {d["Name"]: v for d in displays() for k, v in d.items() if k.endswith("Topic")}


def rviz_commands():
    """(file, command) of every `rviz -d ...` in the README and doc/ (code spans and blocks)."""
    found = []
    for path in [os.path.join(ROOT, "README.md")] + glob.glob(os.path.join(ROOT, "doc", "**", "*.md"), recursive=True):
        with open(path) as f:
            for line in f:
                for m in re.finditer(r"(?:[A-Z_]+=\S+\s+)*rviz\s+-d\s+[^`\n]*", line):
                    found.append((os.path.relpath(path, ROOT), m.group(0).strip()))
    return found


def namespace_of(command):
    """The namespace rviz runs in: __ns:= among its arguments, else ROS_NAMESPACE= before it, else /."""
    words = shlex.split(command.replace("$(", "(").replace(")", ""))
    ns = "/"
    for w in words[:words.index("rviz")]:
        if w.startswith("ROS_NAMESPACE="):
            ns = w.split("=", 1)[1]
    for w in words[words.index("rviz") + 1:]:
        if w.startswith("__ns:="):
            ns = w.split(":=", 1)[1]
    return "/" + ns.strip("/")


def resolve(ns, topic):
    return topic if topic.startswith("/") else ns.rstrip("/") + "/" + topic


def test_the_layout_names_only_the_pipeline_topics_relative():
    published = set(topics_h().values())
    for name, topic in layout_topics().items():
        assert not topic.startswith("/"), "%s: %s is absolute: it would not follow the launch files' ns" % (name, topic)
        assert topic in published, "%s: %s is no topic of topics.h" % (name, topic)


def test_every_rviz_command_of_the_docs_runs_in_the_pipeline_namespace():
    commands = rviz_commands()
    assert any(path == os.path.join("doc", "tutorial.md") for path, _ in commands), commands
    for path, command in commands:
        ns = namespace_of(command)
        wrong = {t: resolve(ns, t) for t in layout_topics().values() if resolve(ns, t) != NS + "/" + t}
        assert not wrong, "%s: `%s` runs rviz in %s: it subscribes to %s, the pipeline publishes under %s" % (
            path, command, ns, sorted(wrong.values()), NS)


def test_every_rviz_node_of_the_launch_files_is_in_the_pipeline_namespace():
    nodes = 0
    for path in glob.glob(os.path.join(ROOT, "launch", "*.launch")):
        for node in ElementTree.parse(path).getroot().iter("node"):
            if node.get("pkg") == "rviz":
                nodes += 1
                assert node.get("ns") == "$(arg ns)", "%s: rviz outside the pipeline's namespace" % path
                assert "uw_multislam.rviz" in node.get("args", "")
    assert nodes >= 1


def test_the_layout_shows_the_status_beside_the_vehicle():
    status = [d for d in displays() if d.get("Marker Topic") == topics_h()["kStatusMarker"]]
    assert len(status) == 1, "no display of the back-end's status marker"
    assert status[0]["Class"] == "rviz/Marker" and status[0]["Enabled"] is True
