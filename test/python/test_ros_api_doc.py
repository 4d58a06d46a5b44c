"""doc/ros_api.md documents every topic, service and parameter the code declares, and nothing else.

What the code declares:
- topic and service names: the constants of include/uw_multislam/ros/topics.h (namespace topics;
  a constant named ...Service is a service, kDefaultSessionFramePrefix is a frame prefix, the
  rest are topics);
- parameters: every call that reads one in the ROS side's sources (src/ros, src/nodelets,
  src/nodes, include/uw_multislam/ros), in any of the forms below; a read through the private
  node handle is the node's ~name, one through the node's namespace a shared name (frames/...);
  a shared name under a node's own namespace (backend_node/publish_odom_tf) is that node's
  private parameter; the SLAM configuration tree is the shared parameter `slam`, whose blocks
  (the top-level keys of config/slam.yaml) are documented as slam/<block>.

What the doc declares: in doc/ros_api.md, a node's section ("## <node>") has the ROS wiki's
subsections (### Subscribed Topics, Published Topics, Services, Services Called, Parameters,
Required tf, Provided tf), each entry a list item starting with the name in backticks
("- `name` (`type`) ..."); "## Shared parameters" lists the shared ones and "## Bag topics" the
topics the bag tools write. Placeholders in a name (`paths/session_<id>`) are dropped.

The checks fail on a declaration the doc leaves out and on a doc entry the code does not
declare; the last tests prove both by mutating copies of the doc and of the sources."""
import os
import re

import pytest

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
DOC = os.path.join(ROOT, "doc", "ros_api.md")
TOPICS_H = os.path.join(ROOT, "include", "uw_multislam", "ros", "topics.h")
SLAM_YAML = os.path.join(ROOT, "config", "slam.yaml")
SOURCE_DIRS = ["src/ros", "src/nodelets", "src/nodes", "include/uw_multislam/ros"]

# The nodes, by the word that names them in a file or function name and in the doc's headings.
NODES = {"odometry": "odometry_node", "loop_detector": "loop_detector_node", "backend": "backend_node"}
NODE_KEYWORDS = [("odometry", "odometry"), ("loop", "loop_detector"), ("backend", "backend")]
# A node's namespace as a shared parameter's first name (odometry_node/..., local_loops_node/...).
NODE_NAMESPACES = {"odometry_node": "odometry", "loop_detector_node": "loop_detector",
                   "local_loops_node": "loop_detector", "global_loops_node": "loop_detector",
                   "backend_node": "backend"}
# Topics the libraries publish for every node (diagnostic_updater), not named in topics.h.
LIBRARY_TOPICS = {"diagnostics"}

PRIVATE_HANDLE = re.compile(r"^(?:this->)?(?:pnh_?|p_nh_?|nhp_?|nh_p_?|nh_private_?|private_nh_?|\w*[Pp]rivate\w*(?:\(\))?)$")
SHARED_HANDLE = re.compile(r"^(?:this->)?(?:nh_?|n|node_?|node_handle_?|mt_nh_?|root_nh_?|getNodeHandle\(\)|"
                           r"getMTNodeHandle\(\))$")
HANDLE = r"(?:this->)?[A-Za-z_]\w*(?:\(\))?"
TEMPLATE_ARGS = r"(?:<[^()]*?>)?"
# Every form a parameter is read in:
#  1. a free function given a node handle and a literal name: param(pnh, "queue_size", ...),
#     ros_params::param<T>(nh, "frames/map_frame", ...), position(nh, "frames/camera_position"), ...
FREE_CALL = re.compile(r"\b(?P<fn>[A-Za-z_][\w:]*)\s*" + TEMPLATE_ARGS + r"\s*\(\s*(?P<h>" + HANDLE +
                       r")\s*,\s*\"(?P<name>[^\"]*)\"")
#  2. a NodeHandle method: pnh.param("x", ...), getNodeHandle().param<T>("x", ...), nh->getParam("x", v),
#     pnh.hasParam("x"), nh.getParamCached / searchParam
METHOD_CALL = re.compile(r"(?P<h>" + HANDLE + r")\s*(?:\.|->)\s*(?P<fn>param|getParam|getParamCached|hasParam|"
                         r"searchParam)\s*" + TEMPLATE_ARGS + r"\s*\(\s*\"(?P<name>[^\"]*)\"")
#  3. ros::param::get("~x", v), ros::param::param<T>("x", ...), ros::param::has / getCached / search
GLOBAL_CALL = re.compile(r"\bros::param::(?:get|param|has|getCached|search)\s*" + TEMPLATE_ARGS +
                         r"\s*\(\s*\"(?P<name>[^\"]*)\"")
#  4. image_transport::TransportHints(..., <private handle>) reads ~image_transport
TRANSPORT_HINTS = re.compile(r"\bTransportHints\s*\((?P<args>[^;]*?)\)\s*[;.]")
#  5. the SLAM configuration tree: slamConfigFromParams(nh) reads `slam` (with a key: form 1)
SLAM_TREE = re.compile(r"\bslamConfigFromParams\s*\(\s*(?P<h>" + HANDLE + r")\s*\)")
# Free functions whose (handle, "literal") arguments are not a parameter name.
NOT_READS = {"resolveName", "advertise", "subscribe", "advertiseService", "serviceClient"}

MIN_PARAMETERS = 50  # distinct parameters read today: about 60
MIN_PRIVATE = 35
MIN_SHARED = 6  # 7 today: the sensors' mount left the frames/ parameters for tf


def strip_comments(text):
    """C++ source without its comments (kept: string literals and line breaks, so positions map to lines)."""
    out, i, n = [], 0, len(text)
    while i < n:
        c = text[i]
        if c == '"' or c == "'":
            j = i + 1
            while j < n and text[j] != c:
                j += 2 if text[j] == "\\" else 1
            out.append(text[i:j + 1])
            i = j + 1
        elif text.startswith("//", i):
            j = text.find("\n", i)
            i = n if j < 0 else j
        elif text.startswith("/*", i):
            j = text.find("*/", i + 2)
            j = n if j < 0 else j + 2
            out.append("\n" * text.count("\n", i, j))
            i = j
        else:
            out.append(c)
            i += 1
    return "".join(out)


def node_of(word):
    word = word.lower()
    for key, node in NODE_KEYWORDS:
        if key in word:
            return node
    return None


FUNCTION_HEAD = re.compile(r"^(?!(?:namespace|template|using|return|if|for|while|switch|static_assert|struct|class|"
                           r"enum|typedef|public|private|protected)\b)[A-Za-z_][^;{}()=]*?\b(\w+)\s*\(")


def enclosing_functions(text):
    """For each line, the name of the function whose definition last started at column 0 above it."""
    names, current = [], None
    for line in text.split("\n"):
        m = FUNCTION_HEAD.match(line)
        if m and not line.rstrip().endswith(";"):
            current = m.group(1)
        names.append(current)
    return names


def classify_handle(handle, where):
    if PRIVATE_HANDLE.match(handle):
        return "private"
    if SHARED_HANDLE.match(handle):
        return "shared"
    raise AssertionError(f"{where}: a parameter read through '{handle}': is that the private node handle or the "
                         "node's namespace? Add its name to PRIVATE_HANDLE or SHARED_HANDLE in this test")


def parameters_in_source(text, path="<source>"):
    """{(scope, name, node)} read in one C++ source; scope 'private' (name without ~) or 'shared';
    node: the node the file or the enclosing function names (odometry, loop_detector, backend) or None."""
    text = strip_comments(text)
    functions = enclosing_functions(text)
    file_node = node_of(os.path.basename(path))
    found = set()

    def add(scope, name, pos, form):
        line = text.count("\n", 0, pos)
        where = f"{path}:{line + 1} ({form})"
        node = file_node or node_of(functions[line] or "")
        if name.startswith("~"):
            scope, name = "private", name[1:]
        assert name and re.fullmatch(r"[A-Za-z_][\w/]*", name), f"{where}: odd parameter name {name!r}"
        first = name.split("/", 1)[0]
        if scope == "shared" and first in NODE_NAMESPACES and "/" in name:
            scope, node, name = "private", NODE_NAMESPACES[first], name.split("/", 1)[1]
        found.add((scope, name, node if scope == "private" else None))

    for m in FREE_CALL.finditer(text):
        fn = m.group("fn").split("::")[-1]
        if fn in NOT_READS or not (PRIVATE_HANDLE.match(m.group("h")) or SHARED_HANDLE.match(m.group("h"))):
            continue
        add(classify_handle(m.group("h"), path), m.group("name"), m.start(), fn + "(handle, name)")
    for m in METHOD_CALL.finditer(text):
        where = f"{path}:{text.count(chr(10), 0, m.start()) + 1}"
        add(classify_handle(m.group("h"), where), m.group("name"), m.start(), "handle." + m.group("fn"))
    for m in GLOBAL_CALL.finditer(text):
        add("shared", m.group("name"), m.start(), "ros::param")
    for m in TRANSPORT_HINTS.finditer(text):
        if any(PRIVATE_HANDLE.match(a.strip()) for a in m.group("args").split(",")):
            add("private", "image_transport", m.start(), "TransportHints")
    for m in SLAM_TREE.finditer(text):
        add(classify_handle(m.group("h"), path), "slam", m.start(), "slamConfigFromParams")
    return found


def code_parameters(root=ROOT):
    found = set()
    for d in SOURCE_DIRS:
        for base, _, files in os.walk(os.path.join(root, d)):
            for f in sorted(files):
                if f.endswith((".cpp", ".h", ".hpp")):
                    path = os.path.join(base, f)
                    with open(path, encoding="utf-8") as fh:
                        found |= parameters_in_source(fh.read(), os.path.relpath(path, root))
    return found


def code_names(topics_h_text):
    """(topics, services) of topics.h's namespace topics."""
    text = strip_comments(topics_h_text)
    m = re.search(r"\bnamespace\s+topics\s*\{", text)
    assert m, "topics.h has no namespace topics"
    depth, end = 1, m.end()
    while depth and end < len(text):
        depth += {"{": 1, "}": -1}.get(text[end], 0)
        end += 1
    body = text[m.end():end]
    topics, services = set(), set()
    for name, value in re.findall(r"constexpr\s+char\s+(k\w+)\s*\[\s*\]\s*=\s*\"([^\"]*)\"", body):
        if name.endswith("Service"):
            services.add(value)
        elif not name.endswith("FramePrefix"):
            topics.add(value)
    return topics, services


def slam_blocks(yaml_text):
    return {m.group(1) for m in re.finditer(r"^([A-Za-z_]\w*)\s*:", yaml_text, re.M)}


SUBSECTIONS = {"subscribed topics": "topic", "published topics": "topic", "services": "service",
               "services called": "service_called", "parameters": "parameter", "required tf": "tf",
               "provided tf": "tf"}


def clean(name):
    name = re.sub(r"<[^>]*>", "", name).strip()
    return name.lstrip("/") if not name.startswith("~") else name


def doc_entries(doc_text):
    """[(section, kind, name)]: section a node (odometry, loop_detector, backend), 'shared' or 'bag'."""
    entries, section, kind = [], None, None
    for line in doc_text.split("\n"):
        if line.startswith("## "):
            title = line[3:].lower()
            section = next((n for n, key in NODES.items() if key in title), None)
            if section is None:
                section = "shared" if "shared parameters" in title else "bag" if "bag topics" in title else None
            kind = {"shared": "parameter", "bag": "topic"}.get(section)
        elif line.startswith("### ") and section in NODES:
            kind = SUBSECTIONS.get(line[4:].strip().lower())
        elif section and kind:
            m = re.match(r"^- `([^`]+)`", line)
            if m:
                entries.append((section, kind, clean(m.group(1))))
    return entries


def check(doc_text, topics, services, parameters, blocks):
    """Every problem, as a sentence; [] when doc and code agree."""
    problems = []
    entries = doc_entries(doc_text)
    documented_topics = {n for _, k, n in entries if k == "topic"}
    provided_services = {n for _, k, n in entries if k == "service"}
    called_services = {n for _, k, n in entries if k == "service_called"}
    for t in sorted(topics - documented_topics):
        problems.append(f"topic '{t}' (topics.h) is not documented")
    for t in sorted(documented_topics - topics - LIBRARY_TOPICS):
        problems.append(f"topic '{t}' is documented but topics.h declares no such topic")
    for s in sorted(services - provided_services):
        problems.append(f"service '{s}' (topics.h) is not documented under a node's Services")
    for s in sorted((provided_services | called_services) - services):
        problems.append(f"service '{s}' is documented but topics.h declares no such service")

    doc_private = {(sec, n[1:]) for sec, k, n in entries if k == "parameter" and n.startswith("~")}
    doc_shared = {n for sec, k, n in entries if k == "parameter" and not n.startswith("~")}
    private = {(name, node) for scope, name, node in parameters if scope == "private"}
    shared = {name for scope, name, _ in parameters if scope == "shared"}
    for name, node in sorted(private, key=str):
        if node is None:
            if not any(n == name for _, n in doc_private):
                problems.append(f"parameter '~{name}' is read but not documented under any node's Parameters")
        elif (node, name) not in doc_private:
            problems.append(f"parameter '~{name}' of {NODES[node]} is read but not documented in its section")
    for sec, name in sorted(doc_private):
        if (name, sec) not in private and (name, None) not in private:
            problems.append(f"parameter '~{name}' is documented for {sec} but the code does not read it there")
    for name in sorted(shared - doc_shared):
        problems.append(f"shared parameter '{name}' is read but not documented")
    for name in sorted(doc_shared - shared):
        block = name.split("/", 1)[1] if name.startswith("slam/") else None
        if block is None or block not in blocks:
            problems.append(f"shared parameter '{name}' is documented but the code does not read it")
    for sec, name in [(sec, n) for sec, k, n in entries if k == "parameter" and sec in NODES and not n.startswith("~")]:
        problems.append(f"parameter '{name}' in {sec}'s section: a node's own parameters are written ~name")
    for block in sorted(blocks):
        if f"slam/{block}" not in doc_shared:
            problems.append(f"config/slam.yaml block '{block}' is not documented (no entry 'slam/{block}')")
    return problems


def read(path):
    with open(path, encoding="utf-8") as f:
        return f.read()


@pytest.fixture(scope="module")
def declared():
    topics, services = code_names(read(TOPICS_H))
    return topics, services, code_parameters(), slam_blocks(read(SLAM_YAML))


def test_the_extraction_finds_what_the_code_declares(declared):
    topics, services, parameters, blocks = declared
    private = [p for p in parameters if p[0] == "private"]
    shared = [p for p in parameters if p[0] == "shared"]
    assert len(parameters) >= MIN_PARAMETERS and len(private) >= MIN_PRIVATE and len(shared) >= MIN_SHARED, (
        f"only {len(parameters)} parameters ({len(private)} private, {len(shared)} shared) found in "
        f"{SOURCE_DIRS}: has a new way of reading parameters appeared? Teach it to this test. Found: {sorted(parameters, key=str)}")
    for node in NODES:
        assert any(p[2] == node for p in private), f"no private parameter attributed to {node}: {sorted(private, key=str)}"
    assert len(topics) >= 20 and len(services) >= 15, (topics, services)
    assert {"odometry", "loops", "backend"} <= blocks, blocks


def test_ros_api_md_documents_exactly_what_the_code_declares(declared):
    problems = check(read(DOC), *declared)
    assert not problems, "doc/ros_api.md and the code disagree:\n" + "\n".join(problems)


def entry_lines(doc_text, section, kind):
    """Line numbers of the doc's entries of one kind in one section."""
    lines, found = doc_text.split("\n"), []
    sec, knd = None, None
    for i, line in enumerate(lines):
        if line.startswith("## "):
            title = line[3:].lower()
            sec = next((n for n, key in NODES.items() if key in title), None) or (
                "shared" if "shared parameters" in title else "bag" if "bag topics" in title else None)
            knd = {"shared": "parameter", "bag": "topic"}.get(sec)
        elif line.startswith("### ") and sec in NODES:
            knd = SUBSECTIONS.get(line[4:].strip().lower())
        elif sec == section and knd == kind and line.startswith("- `"):
            found.append(i)
    return found


@pytest.mark.parametrize("section,kind,expected", [
    ("odometry", "topic", "topic"),
    ("backend", "topic", "topic"),
    ("backend", "service", "service"),
    ("odometry", "parameter", "parameter '~"),
    ("loop_detector", "parameter", "parameter '~"),
    ("backend", "parameter", "parameter '~"),
    ("shared", "parameter", ""),
])
def test_an_entry_left_out_is_found(declared, section, kind, expected):
    """Every entry of a kind, removed from a copy of the doc one at a time, is reported by name
    (unless another section documents the same name, as with the shared topics)."""
    doc = read(DOC)
    lines = doc.split("\n")
    indexes = entry_lines(doc, section, kind)
    assert indexes, f"the doc has no {kind} entries in {section}'s section"
    reported = 0
    for i in indexes:
        name = clean(re.match(r"^- `([^`]+)`", lines[i]).group(1))
        mutated = "\n".join(lines[:i] + lines[i + 1:])
        # A topic or service documented again in another node's section (published by one,
        # subscribed by another) is still documented; a parameter belongs to its own section.
        if any(n == name and k == kind and (kind != "parameter" or sec == section)
               for sec, k, n in doc_entries(mutated)):
            continue
        problems = check(mutated, *declared)
        assert any(expected in p and (f"'{name.lstrip('~')}'" in p or f"'{name}'" in p or f"~{name.lstrip('~')}'" in p)
                   for p in problems), (name, problems)
        reported += 1
    assert reported, f"no {kind} entry of {section} is documented only once"


@pytest.mark.parametrize("entry,section_heading", [
    ("- `no_such_topic` (`std_msgs/Empty`): gone", "### Published Topics"),
    ("- `no_such_service` (`std_srvs/Empty`): gone", "### Services"),
    ("- `~no_such_parameter` (int, default 1): gone", "### Parameters"),
])
def test_an_entry_the_code_does_not_declare_is_found(declared, entry, section_heading):
    doc = read(DOC)
    head = "\n## " + NODES["backend"]
    start = doc.index(head)
    at = doc.index("\n" + section_heading + "\n", start) + len(section_heading) + 2
    mutated = doc[:at] + "\n" + entry + "\n" + doc[at:]
    name = re.match(r"^- `~?([^`]+)`", entry).group(1)
    problems = check(mutated, *declared)
    assert any(name in p and "documented" in p for p in problems), problems


def test_a_shared_parameter_under_a_node_and_a_missing_slam_block_are_found(declared):
    topics, services, parameters, blocks = declared
    assert any("block 'no_such_block'" in p for p in check(read(DOC), topics, services, parameters,
                                                                   blocks | {"no_such_block"}))
    doc = read(DOC)
    at = doc.index("\n### Parameters\n", doc.index("\n## " + NODES["odometry"])) + len("\n### Parameters\n")
    mutated = doc[:at] + "\n- `frames/map_frame` (string): here by mistake\n" + doc[at:]
    assert any("written ~name" in p for p in check(mutated, topics, services, parameters, blocks))


def test_a_new_topic_service_or_parameter_in_the_code_is_found(declared):
    topics, services, parameters, blocks = declared
    doc = read(DOC)
    assert any("'new_topic'" in p for p in check(doc, topics | {"new_topic"}, services, parameters, blocks))
    assert any("'new_service'" in p for p in check(doc, topics, services | {"new_service"}, parameters, blocks))
    added = parameters | {("private", "new_param", "backend"), ("shared", "frames/new_frame", None)}
    problems = check(doc, topics, services, added, blocks)
    assert any("'~new_param' of backend_node" in p for p in problems), problems
    assert any("'frames/new_frame'" in p for p in problems), problems


def test_every_call_form_is_extracted():
    source = r'''
namespace {
int helper() { return 0; }  // param(pnh, "in_a_comment", 1) is no read
}
FooOptions odometryOptions(const ros::NodeHandle& nh, const ros::NodeHandle& pnh) {
  o.a = param(pnh, "queue_size", 5, ok, "");
  o.b = ros_params::param<std::string>(
      nh, "frames/map_frame", std::string("map"), ok, "");
  o.c = position(nh, "frames/camera_position");
  /* pnh.param("in_a_block_comment", 1); */
  nh.param<double>("backend_node/tf_rate", o.d, 20.0);
  if (pnh.hasParam("fleet/peers") && !pnh.getParam("fleet/peers", o.e)) fail();
  getPrivateNodeHandle().getParamCached("cached", o.f);
  ros::param::get("~global_private", o.g);
  const image_transport::TransportHints hints("raw", ros::TransportHints(), getPrivateNodeHandle());
  config = slamConfigFromParams(getNodeHandle());
  ROS_INFO("param(pnh, \"in_a_string\", 1)");
  nh.resolveName("frames");
}
'''
    found = parameters_in_source(source, "src/ros/options.cpp")
    assert found == {
        ("private", "queue_size", "odometry"), ("shared", "frames/map_frame", None),
        ("shared", "frames/camera_position", None), ("private", "tf_rate", "backend"),
        ("private", "fleet/peers", "odometry"), ("private", "cached", "odometry"),
        ("private", "global_private", "odometry"), ("private", "image_transport", "odometry"),
        ("shared", "slam", None)}, sorted(found, key=str)
    # A file named after a node attributes its reads to it; an unknown handle fails loudly.
    assert parameters_in_source('void f() { pnh.param("x", v, 1); }', "src/nodelets/loop_detector_nodelet.cpp") == {
        ("private", "x", "loop_detector")}
    with pytest.raises(AssertionError, match="private node handle or"):
        parameters_in_source('void f() { handle.param("x", v, 1); }', "src/ros/x.cpp")
