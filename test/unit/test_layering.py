"""The core is ROS-free: nothing in src/aruco_abs_orient/ outside ros/ imports rospy, tf2_ros or
cv_bridge (doc/design.md §14: the core runs on a robot's Python without a ROS master, and offline).

An AST scan of every module, so an import inside a function (run only on some path) counts too, as
does ``importlib.import_module("rospy")`` / ``__import__("rospy")`` with a literal name.
"""
import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[2] / "src" / "aruco_abs_orient"
ROS_ONLY = ("rospy", "tf2_ros", "cv_bridge")
ALLOWED = ("ros",)  # sub-packages that are the ROS layer


def ros_imports(source: str, filename: str = "<string>"):
    """(line, module) of every import of a ROS-only module in ``source``."""
    found = []
    for node in ast.walk(ast.parse(source, filename)):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        elif (isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant)
              and isinstance(node.args[0].value, str)
              and ((isinstance(node.func, ast.Name) and node.func.id == "__import__")
                   or (isinstance(node.func, ast.Attribute) and node.func.attr == "import_module"))):
            names = [node.args[0].value]
        found += [(node.lineno, n) for n in names if n.split(".")[0] in ROS_ONLY]
    return found


@pytest.mark.parametrize("source, expected", [
    ("import rospy\n", [(1, "rospy")]),
    ("import os, tf2_ros.buffer as b\n", [(1, "tf2_ros.buffer")]),
    ("def f():\n    from cv_bridge import CvBridge\n", [(2, "cv_bridge")]),
    ("import importlib\nm = importlib.import_module('rospy')\n", [(2, "rospy")]),
    ("x = __import__('tf2_ros')\n", [(1, "tf2_ros")]),
    ("from .ros import conversions\nimport rosbag\nimport rospkg_like\nfrom rosbags.rosbag1 import Reader\n", []),
])
def test_the_scan_finds_ros_imports_in_every_form(source, expected):
    assert ros_imports(source) == expected


def test_nothing_outside_ros_imports_rospy_tf2_ros_or_cv_bridge():
    modules = sorted(PACKAGE.rglob("*.py"))
    assert len(modules) > 30 and (PACKAGE / "detection" / "detector.py") in modules
    offenders = [f"{p.relative_to(PACKAGE)}:{line}: imports {name}"
                 for p in modules if p.relative_to(PACKAGE).parts[0] not in ALLOWED
                 for line, name in ros_imports(p.read_text(encoding="utf-8"), str(p))]
    assert not offenders, "the core must not import ROS (move this into ros/):\n" + "\n".join(offenders)


def test_the_ros_layer_is_where_the_ros_imports_are():
    """The scan reads the real files: the ROS layer does import rospy (else the scan proves nothing)."""
    node = PACKAGE / "ros" / "abs_orient_node.py"
    assert any(name == "rospy" for _, name in ros_imports(node.read_text(encoding="utf-8")))
