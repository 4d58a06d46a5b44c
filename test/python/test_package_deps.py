"""package.xml declares what the code uses, and nothing else.

Checked both ways, from the sources themselves (cheap: no build, no rosdep database):
  - build: every find_package(catkin COMPONENTS ...) component, every find_package(X) of CMakeLists.txt
    and every ROS package or system library a C++ file includes;
  - run: every module the installed Python tools import, every package a launch file starts;
  - test: every module the Python tests (pytest, rostest) import, the test-only CMake packages.
A key used and not declared fails, a key declared and never used fails.
"""
import ast
import glob
import os
import re
import sys

import pytest
from catkin_pkg.package import parse_package

HERE = os.path.dirname(os.path.abspath(__file__))
PKG_DIR = os.path.dirname(os.path.dirname(HERE))

# find_package(X) name -> rosdep key.
CMAKE_PACKAGE_KEYS = {
    "Eigen3": "eigen",
    "OpenCV": "libopencv-dev",
    "yaml-cpp": "yaml-cpp",
    "Ceres": "libceres-dev",
    "SQLite3": "libsqlite3-dev",
    "GeographicLib": "geographiclib",
    "GDAL": "libgdal-dev",
    "Boost": "libboost-program-options-dev",  # its one compiled component the package links (the tools' parser)
    "VLFeat": "libvlfeat-dev",
    "Threads": None,  # the C library, no key
    "catkin": "catkin",
    "roslaunch": "roslaunch",
    "rostest": "rostest",
}
# First directory of a C++ include that is a system library, not a ROS package -> rosdep key
# (None: the C/C++ standard library or the OS).
INCLUDE_KEYS = {
    "opencv2": "libopencv-dev",
    "Eigen": "eigen",
    "ceres": "libceres-dev",
    "yaml-cpp": "yaml-cpp",
    "GeographicLib": "geographiclib",
    "boost": "boost",
    "vl": "libvlfeat-dev",
    "gtest": "gtest",
    "sys": None,
    "uw_multislam": None,
    "ros": "roscpp",  # roscpp's headers are ros/*.h
}
# Include directories more specific than their first one (checked first).
INCLUDE_PREFIX_KEYS = {"boost/program_options": "libboost-program-options-dev"}
INCLUDE_FILE_KEYS = {"sqlite3.h": "libsqlite3-dev", "gdal_priv.h": "libgdal-dev", "ogr_spatialref.h": "libgdal-dev",
                     "cpl_conv.h": "libgdal-dev"}
# Python modules that are not ROS packages -> rosdep key.
PYTHON_KEYS = {"numpy": "python3-numpy", "matplotlib": "python3-matplotlib", "yaml": "python3-yaml",
               "pytest": "python3-pytest", "osgeo": "python3-gdal", "PIL": "python3-pil", "catkin_pkg": "python3-catkin-pkg", "rospkg": "python3-rospkg"}
# ROS packages whose Python module has another name.
ROS_PYTHON_MODULES = {"xmlrpc": None}


def package():
    return parse_package(PKG_DIR)


def declared(kind):
    p = package()
    lists = {
        "build": p.build_depends,
        "exec": p.exec_depends,
        "test": p.test_depends,
        "buildtool": p.buildtool_depends,
    }
    return {d.name for d in lists[kind]}


def cmake_text():
    """CMakeLists.txt with the package's own cmake/*.cmake files it include()s put in their place."""
    def read(path):
        with open(path) as f:
            return re.sub(r"#[^\n]*", "", f.read())

    def inline(m):
        return read(os.path.join(PKG_DIR, "cmake", m.group(1)))

    return re.sub(r"include\(\$\{CMAKE_CURRENT_SOURCE_DIR\}/cmake/([\w.]+\.cmake)\)", inline,
                  read(os.path.join(PKG_DIR, "CMakeLists.txt")))


def catkin_components():
    text = cmake_text()
    sets = {m.group(1): m.group(2).split() for m in re.finditer(r"set\((\w+)\s+([^)]*)\)", text)}
    m = re.search(r"find_package\(catkin\s+REQUIRED\s+COMPONENTS\s+([^)]*)\)", text)
    assert m, "CMakeLists.txt has no find_package(catkin REQUIRED COMPONENTS ...)"
    components = []
    for word in m.group(1).split():
        var = re.fullmatch(r"\$\{(\w+)\}", word)
        components += sets[var.group(1)] if var else [word]
    return components


def cmake_packages():
    """Keys of the find_package calls other than catkin's components: (build keys, test keys)."""
    text = cmake_text()
    testing = text.index("if(CATKIN_ENABLE_TESTING)")
    build, test = set(), set()
    for m in re.finditer(r"find_package\(([^\s)]+)", text):
        name = m.group(1)
        assert name in CMAKE_PACKAGE_KEYS, "find_package(%s): add its rosdep key to CMAKE_PACKAGE_KEYS" % name
        key = CMAKE_PACKAGE_KEYS[name]
        if key and name != "catkin":
            (test if m.start() > testing else build).add(key)
    return build, test


def is_ros_package(name, _rospack=[]):
    import rospkg
    if not _rospack:
        _rospack.append(rospkg.RosPack())
    try:
        _rospack[0].get_path(name)
        return True
    except rospkg.ResourceNotFound:
        return False


def cpp_keys(dirs):
    keys = {}
    for d in dirs:
        for path in glob.glob(os.path.join(PKG_DIR, d, "**", "*"), recursive=True):
            if os.path.splitext(path)[1] not in (".h", ".hpp", ".cpp", ".cc"):
                continue
            with open(path) as f:
                for m in re.finditer(r"^#include <([^>]+)>", f.read(), re.M):
                    inc = m.group(1)
                    if "/" not in inc:
                        key = INCLUDE_FILE_KEYS.get(inc)
                    else:
                        top = inc.split("/")[0]
                        prefix = next((p for p in INCLUDE_PREFIX_KEYS
                                       if inc == p + ".hpp" or inc.startswith(p + "/")), None)
                        if prefix:
                            key = INCLUDE_PREFIX_KEYS[prefix]
                        elif top in INCLUDE_KEYS:
                            key = INCLUDE_KEYS[top]
                        else:
                            assert is_ros_package(top), "%s includes <%s>: not a ROS package; add its key to " \
                                "INCLUDE_KEYS" % (os.path.relpath(path, PKG_DIR), inc)
                            key = top
                    if key:
                        keys.setdefault(key, os.path.relpath(path, PKG_DIR))
    return keys


def python_imports(paths):
    """Top-level module names imported anywhere in the files (also inside functions)."""
    mods = {}
    for path in paths:
        with open(path) as f:
            tree = ast.parse(f.read(), path)
        local = {os.path.splitext(n)[0] for n in os.listdir(os.path.dirname(path)) if n.endswith(".py")}
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names = [node.module]
            else:
                continue
            for name in names:
                top = name.split(".")[0]
                if top not in sys.stdlib_module_names and top not in local:
                    mods.setdefault(top, os.path.relpath(path, PKG_DIR))
    return mods


def python_keys(paths):
    keys = {}
    for mod, where in python_imports(paths).items():
        if mod in PYTHON_KEYS:
            key = PYTHON_KEYS[mod]
        elif mod in ROS_PYTHON_MODULES:
            key = ROS_PYTHON_MODULES[mod]
        else:
            assert is_ros_package(mod), "%s imports %s: neither a ROS package nor in PYTHON_KEYS" % (where, mod)
            key = mod
        if key and key != package().name:
            keys.setdefault(key, where)
    return keys


def launch_keys(pattern):
    keys = {}
    for path in glob.glob(os.path.join(PKG_DIR, pattern)):
        with open(path) as f:
            text = f.read()
        # pkg="...", $(find ...), and nodelet plugins loaded by type ("load pkg/Class", "standalone pkg/Class")
        for m in re.finditer(r'\bpkg="([^"$]+)"|\$\(find ([^)\s]+)\)|\b(?:load|standalone)\s+([a-z][a-z0-9_]*)/', text):
            name = m.group(1) or m.group(2) or m.group(3)
            if name != package().name:
                keys.setdefault(name, os.path.relpath(path, PKG_DIR))
    return keys


def tool_scripts():
    """The installed Python programs: catkin_install_python(PROGRAMS ...) of CMakeLists.txt."""
    with open(os.path.join(PKG_DIR, "CMakeLists.txt")) as f:
        text = f.read()
    programs = []
    for m in re.finditer(r"catkin_install_python\(PROGRAMS(.*?)DESTINATION", text, re.S):
        programs += [os.path.join(PKG_DIR, p) for p in m.group(1).split()]
    assert programs, "no catkin_install_python(PROGRAMS ...) in CMakeLists.txt"
    return sorted(programs)


def python_test_sources():
    return sorted(glob.glob(os.path.join(PKG_DIR, "test", "**", "*.py"), recursive=True))


def used():
    """key -> where it is used, per dependency kind."""
    build = {c: "CMakeLists.txt find_package(catkin COMPONENTS)" for c in catkin_components()}
    cmake_build, cmake_test = cmake_packages()
    build.update({k: "CMakeLists.txt find_package" for k in cmake_build})
    for k, where in cpp_keys(["src", "include"]).items():
        build.setdefault(k, where)
    run = {k: v for k, v in build.items() if k != "message_generation"}
    run["message_runtime"] = "generated messages"
    run.update(python_keys(tool_scripts()))
    run.update(launch_keys("launch/*.launch"))
    test = {k: "CMakeLists.txt find_package (testing)" for k in cmake_test}
    for k, where in list(cpp_keys(["test"]).items()) + list(python_keys(python_test_sources()).items()) + \
            list(launch_keys("test/rostest/*.test").items()):
        test.setdefault(k, where)
    return build, run, test


def test_format_3_with_urls():
    p = package()
    assert p.package_format == 3
    types = {u.type for u in p.urls}
    assert {"repository", "bugtracker"} <= types, types


def test_sqlite_key_is_the_library_not_the_cli():
    assert "libsqlite3-dev" in declared("build")
    assert "sqlite3" not in declared("build") | declared("exec")


def test_every_catkin_component_is_declared():
    missing = [c for c in catkin_components() if c not in declared("build")]
    assert not missing, "find_package(catkin COMPONENTS) names undeclared build dependencies: %s" % missing


def test_what_is_used_is_declared():
    build, run, test = used()
    problems = ["build_depend %s (%s)" % (k, w) for k, w in sorted(build.items()) if k not in declared("build")]
    problems += ["exec_depend %s (%s)" % (k, w) for k, w in sorted(run.items()) if k not in declared("exec")]
    everything = declared("build") | declared("exec") | declared("test")
    problems += ["test_depend %s (%s)" % (k, w) for k, w in sorted(test.items()) if k not in everything]
    assert not problems, "used but not declared in package.xml: " + "; ".join(problems)


def test_what_is_declared_is_used():
    build, run, test = used()
    problems = ["build_depend %s" % k for k in sorted(declared("build") - set(build))]
    problems += ["exec_depend %s" % k for k in sorted(declared("exec") - set(run))]
    problems += ["test_depend %s" % k for k in sorted(declared("test") - set(test))]
    assert not problems, "declared in package.xml but used nowhere: " + ", ".join(problems)


ROSDISTRO_KEYS = os.path.join(HERE, "data", "rosdistro_keys.yaml")
OWN_ROSDEP = os.path.join(PKG_DIR, "rosdep", "uw_multislam.yaml")
INSTALL_DOC = os.path.join(PKG_DIR, "doc", "build_and_test.md")


def every_key():
    p = package()
    return {d.name for kind in (p.build_depends, p.buildtool_depends, p.build_export_depends, p.exec_depends,
                                p.test_depends) for d in kind}


def test_every_key_resolves_through_rosdistro_or_the_repository_rosdep_file():
    """`rosdep install --from-paths` needs every key defined: in rosdistro's rosdep/base.yaml or
    python.yaml or its noetic index (the committed excerpt, with where it came from), or in the
    rosdep source file the repository ships, which the install docs name."""
    import yaml
    with open(ROSDISTRO_KEYS) as f:
        rosdistro = yaml.safe_load(f)
    known = {k for block in rosdistro.values() for k in block}
    with open(OWN_ROSDEP) as f:
        own = yaml.safe_load(f)
    undefined = sorted(every_key() - known - set(own))
    assert not undefined, "package.xml keys no rosdep source defines (%s, %s): %s" % (
        os.path.relpath(ROSDISTRO_KEYS, PKG_DIR), os.path.relpath(OWN_ROSDEP, PKG_DIR), undefined)
    # The repository's file only adds what rosdistro lacks, each for the platforms the docs name.
    assert not set(own) & known, "rosdep/uw_multislam.yaml redefines rosdistro keys: %s" % sorted(set(own) & known)
    for key, rules in own.items():
        assert {"debian", "ubuntu"} <= set(rules), "%s: no debian or ubuntu rule" % key
    with open(INSTALL_DOC) as f:
        assert "rosdep/uw_multislam.yaml" in f.read(), "doc/build_and_test.md does not say how to add the rosdep file"


if __name__ == "__main__":
    sys.exit(pytest.main([__file__, "-q"]))
