"""The import graph of ``src/hdeem_watch`` points one way (issue #13).

The packages are layered ``dram ← {calibrate, sources} ← config ← wire ← daemon ← {tui, cli}``: a package may
import only from a lower tier. The graph is read from the source with :mod:`ast`, so it holds
every import, at module level and inside functions (a function-local import hides a cycle from
the interpreter, not from this test). Imports under ``if TYPE_CHECKING:`` are left out: they
never run.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
ROOT = "hdeem_watch"

#: Tier of every package and top-level module (the part after ``hdeem_watch.``; ``""`` is the
#: package's own ``__init__``). An import must go to a strictly lower tier, so two packages of
#: one tier may not import each other at all.
TIERS: dict[str, int] = {
    "": 0,  # __version__
    "errors": 0,
    "channels": 0,  # the channel vocabulary (HDEEM names, DIMM pairs, sockets)
    "addresses": 0,  # which endpoints stay on the node (config and daemon both ask)
    "perf_event": 0,  # perf_event_open through ctypes (sources: RAPL energy; counters: the IMC PMUs)
    "dram": 1,  # the DRAM model: memspecs, statistics, energy, controller
    "calibrate": 2,  # rows and fits on the model
    "sources": 2,  # power sensors (the sim models its DRAM with dram/)
    "node": 2,  # facts about this machine (topology, DIMMs, sensor map)
    "counters": 2,  # memory-controller counters -> command statistics (uses dram/)
    "config": 3,  # the daemon's settings (with each source's options)
    "wire": 4,  # protocol v1, control client, client keys: what daemon and clients share
    "daemon": 5,
    "slurm": 6,  # the SLURM adapter (talks to the daemon)
    "tui": 7,
    "bench": 7,
    "report": 7,  # figures from a daemon's state or a RUNS.json
    "metricq": 7,  # the daemon's stream to a MetricQ broker (a client of the daemon)
    "demo": 8,  # a demo node: daemon + bench schedule, shown by the TUI
    "cli": 9,
    "__main__": 10,
}

#: Packages inside which no two modules may import each other in a cycle.
ACYCLIC_PACKAGES = ("dram", "wire", "daemon", "calibrate")


@dataclass(frozen=True)
class Edge:
    """One import statement: ``source`` imports ``target`` at ``path:line``."""

    source: str
    target: str
    path: str
    line: int

    def __str__(self) -> str:
        return f"{self.source} -> {self.target} ({self.path}:{self.line})"


def module_names(src: Path = SRC) -> dict[str, Path]:
    """Every module of the package under ``src`` by dotted name (packages by their ``__init__``)."""
    names = {}
    for path in sorted((src / ROOT).rglob("*.py")):
        parts = list(path.relative_to(src).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        names[".".join(parts)] = path
    return names


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _import_nodes(node: ast.AST) -> Iterator[ast.Import | ast.ImportFrom]:
    """Every import below ``node`` at any depth, except inside ``if TYPE_CHECKING:``."""
    for child in ast.iter_child_nodes(node):
        if isinstance(child, ast.If) and _is_type_checking(child.test):
            yield from _imports_of(child.orelse)
        else:
            yield from _imports_of([child])


def _imports_of(nodes: list[ast.stmt] | list[ast.AST]) -> Iterator[ast.Import | ast.ImportFrom]:
    for node in nodes:
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
        yield from _import_nodes(node)


def import_edges(src: Path = SRC) -> list[Edge]:
    """Every import from one module of the package under ``src`` to another."""
    modules = module_names(src)
    edges = []
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        shown = str(path.relative_to(src.parent))
        for node in _import_nodes(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            else:
                if node.level:
                    base = package.split(".")[: len(package.split(".")) - node.level + 1]
                    stem = ".".join(base + ([node.module] if node.module else []))
                else:
                    stem = node.module or ""
                # ``from pkg import mod`` imports the module pkg.mod; ``from mod import name``
                # imports mod.
                targets = [
                    f"{stem}.{alias.name}" if f"{stem}.{alias.name}" in modules else stem
                    for alias in node.names
                ]
            for target in dict.fromkeys(targets):
                if target in modules and target != name:
                    edges.append(Edge(name, target, shown, node.lineno))
    return edges


def area(module: str) -> str:
    """The package or top-level module ``module`` belongs to (``""`` for the root)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def find_cycles(edges: list[Edge], node_of: dict[str, str]) -> list[list[str]]:
    """Strongly connected components with more than one node of the graph ``edges`` induces
    on ``node_of`` (module → graph node; modules not in it are left out)."""
    graph: dict[str, set[str]] = {}
    for edge in edges:
        a, b = node_of.get(edge.source), node_of.get(edge.target)
        if a is not None and b is not None and a != b:
            graph.setdefault(a, set()).add(b)
            graph.setdefault(b, set())
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []

    def visit(v: str) -> None:  # Tarjan; the graphs here are a few dozen nodes deep at most
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
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
                components.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return components


def describe(component: list[str], edges: list[Edge], node_of: dict[str, str]) -> str:
    """The imports that close the cycle ``component``, one per line."""
    members = set(component)
    inside = [
        str(e)
        for e in edges
        if node_of.get(e.source) in members
        and node_of.get(e.target) in members
        and node_of[e.source] != node_of[e.target]
    ]
    return " <-> ".join(component) + "\n    " + "\n    ".join(inside)


@pytest.fixture(scope="module")
def edges() -> list[Edge]:
    found = import_edges()
    assert len(found) > 100, "the import graph is suspiciously small: is the parser broken?"
    return found


def test_the_parser_sees_imports_at_every_depth_except_type_checking() -> None:
    """The import finder looks inside functions, classes and else branches, and skips only
    ``if TYPE_CHECKING:`` blocks."""
    tree = ast.parse(
        "import a\n"
        "from typing import TYPE_CHECKING\n"
        "if TYPE_CHECKING:\n    import hidden\nelse:\n    import shown\n"
        "def f():\n    from b import c\n    class K:\n        import d\n"
    )
    found = [
        alias.name if isinstance(n, ast.Import) else n.module
        for n in _import_nodes(tree)
        for alias in n.names
    ]
    assert found == ["a", "typing", "shown", "b", "d"]


def test_edges_resolve_relative_and_from_package_imports(tmp_path: Path) -> None:
    """``from . import mod``, ``from ..pkg import mod``, ``from pkg import name`` and
    ``import pkg.mod`` become edges to the module they load (a package's own ``__init__`` when a
    name is not a module); imports outside the package are no edges."""
    files = {
        "hdeem_watch/__init__.py": "",
        "hdeem_watch/a/__init__.py": "from hdeem_watch.a.x import thing\n",
        "hdeem_watch/a/x.py": "from . import y\nimport numpy\n"
                              "def f():\n    from ..b import z\n    import hdeem_watch.b.z\n",
        "hdeem_watch/a/y.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from hdeem_watch.b import z\n",
        "hdeem_watch/b/__init__.py": "",
        "hdeem_watch/b/z.py": "from hdeem_watch.a import thing\n",
    }
    for name, text in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    found = {(e.source, e.target, e.line) for e in import_edges(tmp_path)}
    assert found == {
        ("hdeem_watch.a", "hdeem_watch.a.x", 1),
        ("hdeem_watch.a.x", "hdeem_watch.a.y", 1),
        ("hdeem_watch.a.x", "hdeem_watch.b.z", 4),
        ("hdeem_watch.a.x", "hdeem_watch.b.z", 5),
        ("hdeem_watch.b.z", "hdeem_watch.a", 1),
    }
    node_of = {m: area(m) for m in module_names(tmp_path)}
    assert find_cycles(import_edges(tmp_path), node_of) == [["a", "b"]]


def test_every_package_has_a_tier(edges: list[Edge]) -> None:
    """A new package or top-level module must be placed in the layering on purpose."""
    missing = sorted({area(m) for m in module_names()} - set(TIERS))
    assert not missing, f"add to TIERS in tests/test_layering.py: {missing}"


def test_no_cycle_between_packages(edges: list[Edge]) -> None:
    """No two packages (or top-level modules) import each other, directly or around a loop."""
    node_of = {m: area(m) or ROOT for m in module_names()}
    cycles = find_cycles(edges, node_of)
    assert not cycles, "package cycles:\n" + "\n".join(
        describe(c, edges, node_of) for c in cycles
    )


@pytest.mark.parametrize("package", ACYCLIC_PACKAGES)
def test_no_cycle_between_modules_of(package: str, edges: list[Edge]) -> None:
    """Inside ``package`` the modules form a DAG (function-local imports included)."""
    node_of = {m: m for m in module_names() if area(m) == package}
    cycles = find_cycles(edges, node_of)
    assert not cycles, f"module cycles in {package}/:\n" + "\n".join(
        describe(c, edges, node_of) for c in cycles
    )


@pytest.mark.parametrize("package", sorted(TIERS), ids=lambda name: name or ROOT)
def test_imports_point_down_the_layers(package: str, edges: list[Edge]) -> None:
    """dram ← {calibrate, sources} ← daemon ← {tui, cli}: ``package`` imports only lower tiers."""
    upward = [
        f"{e}  [tier {TIERS[package]} -> tier {TIERS.get(area(e.target))}]"
        for e in edges
        if area(e.source) == package != area(e.target)
        and TIERS[package] <= TIERS.get(area(e.target), 99)
    ]
    assert not upward, f"imports of {package or ROOT} against the layering:\n" + "\n".join(upward)


#: The daemon's clients: they speak to a daemon through :mod:`hdeem_watch.wire` only.
CLIENTS = ("tui", "bench", "slurm", "metricq", "report", "cli", "demo")
#: Client modules that may import the daemon: the command that runs one. ``demo.sim_runs`` runs
#: the daemon's run modelling without a daemon; it leaves this list when that pure code moves out
#: of the daemon into ``calibrate/`` (issue #26).
RUNS_A_DAEMON = {"hdeem_watch.cli.daemon", "hdeem_watch.demo.sim_runs"}


def test_clients_import_nothing_of_the_daemon(edges: list[Edge]) -> None:
    """Issue #26: TUI, bench, SLURM hooks, MetricQ, report, command line and demo import the wire
    package, never ``hdeem_watch.daemon`` (the command that runs a daemon aside)."""
    into_daemon = [
        str(e) for e in edges
        if area(e.source) in CLIENTS and area(e.target) == "daemon" and e.source not in RUNS_A_DAEMON
    ]
    assert not into_daemon, "clients importing the daemon:\n" + "\n".join(into_daemon)
    assert any(area(e.source) in CLIENTS and area(e.target) == "wire" for e in edges)
