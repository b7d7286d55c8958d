"""The package's shape, checked by `make lint` and test/unit/test_structure.py: sizes and imports.

In: the Python modules under src/aruco_abs_orient (or the directory given). Out: one line per offence
(``path:line: what``) and exit status 1, or nothing and 0. The rules:

- a module has at most MAX_MODULE_LINES lines, a function at most MAX_FUNCTION_LINES (its docstring too);
- no import cycle between the package's modules: every ``import`` counts, also one inside a function (a
  cycle hidden behind a late import is still two modules that need each other); one under
  ``if TYPE_CHECKING:`` does not (it never runs). ``from . import x`` is an
  edge to the module ``x``; ``from .pkg import name`` to ``pkg.name`` when that is a module, else to ``pkg``.

Run: ``python tools/check_structure.py [--sizes-warn-only] [DIR]``; with ``--sizes-warn-only`` the sizes are
printed but only an import cycle fails (exit 1).
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path
from typing import Dict, Iterator, List, Set, Tuple

MAX_MODULE_LINES = 600
MAX_FUNCTION_LINES = 80
PACKAGE_DIR = Path(__file__).resolve().parents[1] / "src" / "aruco_abs_orient"


def module_name(path: Path, root: Path) -> str:
    """``root/a/b.py`` → ``a.b``; ``root/a/__init__.py`` → ``a``; ``root/__init__.py`` → ``''``."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def size_offences(path: Path, source: str, label: str) -> List[str]:
    """A module over MAX_MODULE_LINES lines, each function over MAX_FUNCTION_LINES."""
    out = []
    lines = source.count("\n")
    if lines > MAX_MODULE_LINES:
        out.append(f"{label}:1: {lines} lines (at most {MAX_MODULE_LINES})")
    for node in ast.walk(ast.parse(source, str(path))):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            n = node.end_lineno - node.lineno + 1
            if n > MAX_FUNCTION_LINES:
                out.append(f"{label}:{node.lineno}: function {node.name} has {n} lines (at most {MAX_FUNCTION_LINES})")
    return out


def _type_checking_only(tree: ast.AST) -> Set[ast.AST]:
    """The import statements under ``if TYPE_CHECKING:`` (never run: annotations only)."""
    return {inner for node in ast.walk(tree) if isinstance(node, ast.If) and isinstance(node.test, ast.Name)
            and node.test.id == "TYPE_CHECKING" for stmt in node.body for inner in ast.walk(stmt)}


def _imports(tree: ast.AST, name: str, is_package: bool, modules: Set[str]) -> Iterator[Tuple[int, str]]:
    """(line, module of the package) of every import in ``tree`` (the module ``name``) that can run."""
    skip = _type_checking_only(tree)
    for node in ast.walk(tree):
        if node in skip:
            continue
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith("aruco_abs_orient."):
                    yield node.lineno, alias.name[len("aruco_abs_orient."):]
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                if not (node.module or "").startswith("aruco_abs_orient"):
                    continue
                base = node.module[len("aruco_abs_orient."):] if "." in node.module else ""
            else:
                here = name.split(".") if name else []
                up = node.level - 1 if is_package else node.level
                if up > len(here):
                    continue
                base = ".".join(here[:len(here) - up] + ([node.module] if node.module else []))
            for alias in node.names:
                sub = f"{base}.{alias.name}" if base else alias.name
                yield node.lineno, sub if sub in modules else base


def import_graph(root: Path) -> Dict[str, Dict[str, int]]:
    """module → {module it imports: line}, over the package's modules under ``root``."""
    paths = {module_name(p, root): p for p in sorted(root.rglob("*.py"))}
    graph: Dict[str, Dict[str, int]] = {}
    for name, path in paths.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        edges: Dict[str, int] = {}
        for line, target in _imports(tree, name, path.name == "__init__.py", set(paths)):
            if target in paths and target != name:
                edges.setdefault(target, line)
        graph[name] = edges
    return graph


def cycles(graph: Dict[str, Dict[str, int]]) -> List[List[str]]:
    """The import cycles of ``graph``: each strongly connected component of more than one module (Tarjan)."""
    index: Dict[str, int] = {}
    low: Dict[str, int] = {}
    stack: List[str] = []
    on_stack: Set[str] = set()
    found: List[List[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, {}):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def all_size_offences(root: Path = PACKAGE_DIR) -> List[str]:
    """The modules and functions under ``root`` over the size limits."""
    out = []
    for path in sorted(root.rglob("*.py")):
        out += size_offences(path, path.read_text(encoding="utf-8"), str(path.relative_to(root.parent)))
    return out


def cycle_offences(root: Path = PACKAGE_DIR) -> List[str]:
    """One line per import cycle under ``root``, naming the imports that close it."""
    out = []
    graph = import_graph(root)
    for component in cycles(graph):
        members = set(component)
        links = ", ".join(f"{a} → {b} (line {graph[a][b]})" for a in component for b in sorted(graph[a])
                          if b in members)
        out.append(f"import cycle between {', '.join(component)}: {links}")
    return out


def offences(root: Path = PACKAGE_DIR) -> List[str]:
    """Every offence against the rules above under ``root`` (the package directory)."""
    return all_size_offences(root) + cycle_offences(root)


def main(argv: List[str]) -> int:
    warn_only = "--sizes-warn-only" in argv
    args = [a for a in argv if a != "--sizes-warn-only"]
    root = Path(args[0]) if args else PACKAGE_DIR
    sizes, found = all_size_offences(root), cycle_offences(root)
    for line in sizes:
        print(f"warning: {line}" if warn_only else line)
    for line in found:
        print(line)
    return 1 if found or (sizes and not warn_only) else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
