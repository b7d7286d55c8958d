"""The package's shape (tools/check_structure.py, also run by `make lint`): no import cycle anywhere in src/, no
module over 600 lines, no function over 80. The checker is tried on small packages written here first, so that a
pass on the real one means something."""
import importlib.util
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("check_structure", ROOT / "tools" / "check_structure.py")
check = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(check)


def _package(tmp_path: Path, files: dict) -> Path:
    root = tmp_path / "pkg"
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text))
    return root


def test_the_checker_finds_cycles_in_every_import_form(tmp_path):
    root = _package(tmp_path, {
        "__init__.py": "",
        "a.py": "from .b import thing\n",
        "b.py": "def f():\n    from . import c\n",            # a late import counts
        "c.py": "from aruco_abs_orient.a import x\n",        # absolute, back to a
        "d.py": "from .sub import helper\n",
        "sub/__init__.py": "from .inner import helper\n",
        "sub/inner.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from ..d import D\n",
        "e.py": "from .f import y\n",
        "f.py": "import os\n",
    })
    graph = check.import_graph(root)
    assert graph["a"] == {"b": 1} and graph["b"] == {"c": 2} and graph["c"] == {"a": 1}
    assert graph["sub.inner"] == {}                          # TYPE_CHECKING: never runs
    assert check.cycles(graph) == [["a", "b", "c"]]
    assert any("import cycle between a, b, c" in line for line in check.offences(root))


def test_the_checker_finds_long_modules_and_functions(tmp_path):
    body = "\n".join(f"    x{i} = {i}" for i in range(check.MAX_FUNCTION_LINES))
    root = _package(tmp_path, {"__init__.py": "", "long.py": f"def long():\n{body}\n\n\ndef short():\n    pass\n",
                               "big.py": "x = 1\n" * (check.MAX_MODULE_LINES + 1)})
    found = check.offences(root)
    assert any(f"long.py:1: function long has {check.MAX_FUNCTION_LINES + 1} lines" in line for line in found)
    assert not any("short" in line for line in found)
    assert any(f"big.py:1: {check.MAX_MODULE_LINES + 1} lines" in line for line in found)


def test_no_import_cycle_in_the_package():
    graph = check.import_graph(check.PACKAGE_DIR)
    assert len(graph) > 80 and "calibration" in graph["offline.calibrate"]
    assert not any("offline.cli" in edges for edges in graph.values()), "nothing imports the CLI's dispatch"
    found = check.cycles(graph)
    assert not found, f"import cycles in src/aruco_abs_orient: {found}"


def test_sizes_warn_only_prints_sizes_and_fails_only_on_cycles(tmp_path, capsys):
    body = "\n".join(f"    x{i} = {i}" for i in range(check.MAX_FUNCTION_LINES))
    long = {"__init__.py": "", "long.py": f"def long():\n{body}\n"}
    root = _package(tmp_path / "sizes", long)
    assert check.main([str(root)]) == 1
    assert check.main(["--sizes-warn-only", str(root)]) == 0
    assert "warning: pkg/long.py:1: function long" in capsys.readouterr().out
    cyclic = _package(tmp_path / "cycle", {**long, "a.py": "from . import b\n", "b.py": "from . import a\n"})
    assert check.main(["--sizes-warn-only", str(cyclic)]) == 1


def test_no_module_or_function_over_the_limits():
    found = check.all_size_offences(check.PACKAGE_DIR)
    assert not found, "over the limits:\n" + "\n".join(found)
