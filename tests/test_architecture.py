"""Architecture rules of lidar3d/, checked on the source with ``ast`` (nothing is imported).

* no import circle among the modules of ``lidar3d/``;
* the algorithm packages never import an adapter or driver (DESIGN.md section 1);
* no class longer than 200 lines (issue 14).

The import graph has an edge ``A -> B`` for every ``import`` / ``from ... import`` statement in
module ``A``, at module level or inside a function or class, that runs or reads module ``B``:

* ``import a.b.c`` and ``from a.b.c import ...`` run ``a.b.c`` and its enclosing packages ``a`` and
  ``a.b``, except ``A`` itself and the packages enclosing ``A`` (already being imported when ``A``
  runs: a submodule importing its siblings is no circle with its package's ``__init__``);
* ``from a.b import c`` with ``c`` a submodule runs ``a.b.c``;
* ``from a.b import name`` with ``name`` not a submodule reads ``a.b``'s namespace: an edge to
  ``a.b`` even when ``a.b`` encloses ``A`` (it would be read half-initialised).

Relative imports are resolved against ``A``'s package. Only modules inside the scanned package
count; ``importlib.import_module`` calls are not import statements and are not followed.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path

PACKAGE_ROOT = Path(__file__).resolve().parents[1] / "lidar3d"

ALGORITHM_PACKAGES = ("lidar3d.segmentation", "lidar3d.features", "lidar3d.mapping", "lidar3d.loop")
ADAPTERS_AND_DRIVERS = (
    "lidar3d.io",
    "lidar3d.cli",
    "lidar3d.batch",
    "lidar3d.export",
    "lidar3d.run",
    "lidar3d.grid",
    "lidar3d.pipeline",
    "lidar3d.prefetch",
    "lidar3d.sim",
)
MAX_CLASS_LINES = 200


@dataclass(frozen=True, slots=True)
class ImportEdge:
    """Module ``source`` runs module ``target`` through the import statement at ``source``'s ``line``."""

    source: str
    target: str
    line: int


def module_files(package_dir: Path) -> dict[str, Path]:
    """Dotted module name -> file for every ``.py`` file under ``package_dir`` (a package's
    ``__init__.py`` is the package itself)."""
    modules = {}
    for path in sorted(package_dir.rglob("*.py")):
        parts = path.relative_to(package_dir.parent).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        modules[".".join(parts)] = path
    return modules


def _enclosing_packages(module: str) -> list[str]:
    """``a.b.c`` -> ``["a", "a.b"]``."""
    parts = module.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts))]


def _resolve_relative(module: str, is_package: bool, level: int, name: str | None) -> str:
    """The absolute module named by ``from <level dots><name> import ...`` inside ``module``."""
    parts = module.split(".")
    base = parts if is_package else parts[:-1]
    if level > 1:
        base = base[: len(base) - (level - 1)]
    return ".".join(base + ([name] if name else []))


def import_edges(package_dir: Path) -> list[ImportEdge]:
    """Every import edge between modules of the package at ``package_dir`` (see module docstring)."""
    modules = module_files(package_dir)
    edges = []
    for module, path in modules.items():
        is_package = path.name == "__init__.py"
        already_running = {*_enclosing_packages(module), module}
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
            if isinstance(node, ast.Import):
                imported = [alias.name for alias in node.names]
                read_from: list[str] = []
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = _resolve_relative(module, is_package, node.level, node.module)
                else:
                    base = node.module or ""
                submodules = [f"{base}.{a.name}" for a in node.names if f"{base}.{a.name}" in modules]
                imported = [base]
                read_from = submodules + ([base] if len(submodules) < len(node.names) else [])
            else:
                continue
            runs = [p for name in imported for p in (*_enclosing_packages(name), name) if p not in already_running]
            for target in dict.fromkeys(runs + read_from):
                if target in modules and target != module:
                    edges.append(ImportEdge(module, target, node.lineno))
    return edges


def find_cycles(edges: list[ImportEdge]) -> list[list[str]]:
    """One circle per strongly connected component of two or more modules (Tarjan's algorithm;
    edges never join a module to itself): ``[m0, m1, ..., m0]`` along edges, sorted."""
    graph: dict[str, list[str]] = {}
    for edge in edges:
        graph.setdefault(edge.source, []).append(edge.target)
        graph.setdefault(edge.target, [])
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[set[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for succ in graph[node]:
            if succ not in index:
                visit(succ)
                low[node] = min(low[node], low[succ])
            elif succ in on_stack:
                low[node] = min(low[node], index[succ])
        if low[node] == index[node]:
            component = set()
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.add(member)
                if member == node:
                    break
            if len(component) > 1:
                components.append(component)

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return sorted(_circle_through(graph, component) for component in components)


def _circle_through(graph: dict[str, list[str]], component: set[str]) -> list[str]:
    """A shortest circle from the component's first module back to itself, inside the component."""
    start = min(component)
    previous: dict[str, str] = {}
    frontier = [start]
    while frontier:
        following = []
        for node in frontier:
            for succ in sorted(set(graph[node]) & component):
                if succ == start:
                    path = [node]
                    while path[-1] != start:
                        path.append(previous[path[-1]])
                    return [*reversed(path), start]
                if succ not in previous:
                    previous[succ] = node
                    following.append(succ)
        frontier = following
    raise AssertionError(f"no circle through {start}")  # unreachable for a strongly connected component


def _describe(circle: list[str], edges: list[ImportEdge]) -> str:
    """``a (line 3) -> b (line 7) -> a``: each module with the line of its first import of the next."""
    lines: dict[tuple[str, str], int] = {}
    for e in edges:
        lines.setdefault((e.source, e.target), e.line)
    steps = [f"{a} (line {lines[a, b]})" for a, b in pairwise(circle)]
    return " -> ".join([*steps, circle[-1]])


def class_lengths(package_dir: Path) -> list[tuple[str, int]]:
    """(``module.Class``, lines from the ``class`` line to its last line) for every class, nested
    ones included."""
    out = []
    for module, path in module_files(package_dir).items():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
            if isinstance(node, ast.ClassDef):
                assert node.end_lineno is not None
                out.append((f"{module}.{node.name}", node.end_lineno - node.lineno + 1))
    return out


def _inside(module: str, packages: tuple[str, ...]) -> bool:
    return any(module == p or module.startswith(p + ".") for p in packages)


def layer_violations(edges: list[ImportEdge]) -> list[ImportEdge]:
    """The edges from an algorithm package to an adapter or driver."""
    return [e for e in edges if _inside(e.source, ALGORITHM_PACKAGES) and _inside(e.target, ADAPTERS_AND_DRIVERS)]


# -- the rules ------------------------------------------------------------------------------------


def test_no_import_circle_in_lidar3d():
    edges = import_edges(PACKAGE_ROOT)
    circles = find_cycles(edges)
    assert not circles, "import circles in lidar3d/:\n" + "\n".join(_describe(c, edges) for c in circles)


def test_algorithm_packages_import_no_adapter_or_driver():
    assert set(ALGORITHM_PACKAGES) <= set(module_files(PACKAGE_ROOT)), f"not the lidar3d tree: {PACKAGE_ROOT}"
    bad = [f"{e.source} line {e.line} imports {e.target}" for e in layer_violations(import_edges(PACKAGE_ROOT))]
    assert not bad, "algorithm packages importing adapters or drivers:\n" + "\n".join(sorted(bad))


def test_no_class_longer_than_200_lines():
    long = sorted(f"{name}: {n} lines" for name, n in class_lengths(PACKAGE_ROOT) if n > MAX_CLASS_LINES)
    assert not long, f"classes over {MAX_CLASS_LINES} lines:\n" + "\n".join(long)


# -- the checks themselves, on a planted package ------------------------------------------------


def _write_files(root: Path, files: dict[str, str]) -> None:
    for relative, text in files.items():
        path = root / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")


def test_cycle_finder_finds_a_planted_circle(tmp_path):
    _write_files(
        tmp_path,
        {
            # the usual package pattern is no circle: __init__ re-exports, submodules import siblings
            "pkg/__init__.py": "from pkg.a import f\nfrom . import plain\n",
            "pkg/plain.py": "import os\nfrom pkg import sub\nimport pkg.sub.leaf\n",
            "pkg/sub/__init__.py": "",
            "pkg/sub/leaf.py": "from ..util import helper\n",
            "pkg/util.py": "def helper():\n    pass\n",
            # the circle: a -> b (relative) -> c (inside a function) -> a (from package import name)
            "pkg/a.py": "from . import b\n\ndef f():\n    return b\n",
            "pkg/b.py": "def g():\n    from pkg.sub.c import h\n    return h\n",
            "pkg/sub/c.py": "from ..a import f as h\n",
        },
    )
    package = tmp_path / "pkg"
    edges = import_edges(package)
    pairs = {(e.source, e.target) for e in edges}
    assert ("pkg.a", "pkg.b") in pairs and ("pkg.b", "pkg.sub.c") in pairs and ("pkg.sub.c", "pkg.a") in pairs
    assert ("pkg.plain", "pkg.sub") in pairs and ("pkg.plain", "pkg.sub.leaf") in pairs
    assert ("pkg.sub.leaf", "pkg.util") in pairs and ("pkg.sub.leaf", "pkg") not in pairs
    circles = find_cycles(edges)
    assert circles == [["pkg.a", "pkg.b", "pkg.sub.c", "pkg.a"]]
    assert _describe(circles[0], edges) == "pkg.a (line 1) -> pkg.b (line 2) -> pkg.sub.c (line 1) -> pkg.a"
    # reading a name from one's own half-initialised package is a circle too
    (package / "plain.py").write_text("from pkg import f\n", encoding="utf-8")
    assert ["pkg", "pkg.plain", "pkg"] in find_cycles(import_edges(package))


def test_layer_and_class_checks_see_a_planted_violation(tmp_path):
    _write_files(
        tmp_path,
        {
            "lidar3d/__init__.py": "",
            "lidar3d/io/__init__.py": "",
            "lidar3d/io/pcd.py": "",
            "lidar3d/loop/__init__.py": "",
            "lidar3d/loop/closer.py": "def f():\n    from lidar3d.io import pcd\n",
            "lidar3d/loop/big.py": "class Big:\n" + "    x = 1\n" * MAX_CLASS_LINES,
        },
    )
    package = tmp_path / "lidar3d"
    bad = [(e.source, e.target) for e in layer_violations(import_edges(package))]
    assert bad == [("lidar3d.loop.closer", "lidar3d.io"), ("lidar3d.loop.closer", "lidar3d.io.pcd")]
    assert ("lidar3d.loop.big.Big", MAX_CLASS_LINES + 1) in class_lengths(package)
