"""The import graph of ``src/hdeem_watch`` points one way (issues #13, #26), and its functions stay short.

The packages are layered ``dram ← counters ← sim ← sources ← {calibrate, node} ← config ← wire ← daemon ← {tui, cli}``: a package may
import only from a lower tier, and no two modules anywhere import each other, directly or around a
loop. The graph is read from the source with :mod:`ast`, so it holds every import, at module level
and inside functions (a function-local import hides a cycle from the interpreter, not from this
test). Imports under ``if TYPE_CHECKING:`` are left out: they never run.

No function in ``src/`` is longer than :data:`MAX_FUNCTION_LINES` (80); those that were when the rule
came were listed in :data:`LONG_FUNCTIONS` with their length then, and could only shrink (none is left).
"""

from __future__ import annotations

import ast
import functools
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

# One worker runs the module, so the package is parsed once per test run, not once per worker.
pytestmark = pytest.mark.xdist_group("layering")

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
    "run_record": 0,  # one run as daemon, store, report, TUI and calibrator see it (one parser)
    "fit_record": 0,  # one calibration fit as TUI, report and the store's checks read it (one parser)
    "record_fields": -1,  # the tolerant field reader under the fit and job records (below them)
    "job_record": 0,  # one SLURM job as daemon, store, report, CLI and hooks see it (one parser)
    "state_schema": 0,  # the SQLite state file's tables (the daemon writes them, the report reads them)
    "perf_event": 0,  # perf_event_open through ctypes (sources: RAPL energy; counters: the IMC PMUs)
    "dram": 1,  # the DRAM model: memspecs, statistics, energy, controller
    "counters": 2,  # memory-controller counters -> command statistics (uses dram/)
    "sim": 3,  # the simulated node: its truth (dram/), its IMC counters (counters/)
    "sources": 4,  # power sensors (the sim source adapts sim/)
    "calibrate": 5,  # rows and fits on the model; a run's model, per-group fits (a source's layout), the counter model
    "node": 5,  # facts about this machine (topology, DIMMs, sensor map, its DRAM energy source: RAPL zones)
    "config": 6,  # the daemon's settings (with each source's options)
    "wire": 7,  # protocol v1, control client, client keys: what daemon and clients share
    "daemon": 8,
    "slurm": 9,  # the SLURM adapter (talks to the daemon)
    "tui": 10,
    "bench": 10,
    "report": 10,  # figures from a daemon's state or a RUNS.json
    "metricq": 10,  # the daemon's stream to a MetricQ broker (a client of the daemon)
    "demo": 11,  # a demo node: daemon + bench schedule, shown by the TUI
    "cli": 12,
    "__main__": 13,
}

#: Packages whose module cycles get a test of their own (for a clear message; the rule itself,
#: no circle between any two modules, is :func:`test_no_cycle_between_any_modules`).
ACYCLIC_PACKAGES = ("dram", "wire", "daemon", "calibrate", "sources", "counters", "sim")

#: The longest a function (``def`` line to last line, docstring included) may be.
MAX_FUNCTION_LINES = 80

#: Functions over :data:`MAX_FUNCTION_LINES` when the rule came (issue #26), by
#: ``path:qualified name`` with their length then. One may shrink (then lower or drop its entry),
#: never grow; a function not listed may not pass the limit.
LONG_FUNCTIONS: dict[str, int] = {}


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


@functools.cache
def parsed(path: Path) -> ast.Module:
    """The syntax tree of ``path``, parsed once per process (the import graph and the function
    lengths walk the same ~300 modules; each parse of them all costs ~1 s)."""
    return ast.parse(path.read_text(encoding="utf-8"))


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
        for node in _import_nodes(parsed(path)):
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


def test_no_cycle_between_any_modules(edges: list[Edge]) -> None:
    """No module imports itself back through others, wherever they sit (function-local imports
    included; a package's ``__init__`` is a module of its own)."""
    node_of = {m: m for m in module_names()}
    cycles = find_cycles(edges, node_of)
    assert not cycles, "module cycles:\n" + "\n".join(describe(c, edges, node_of) for c in cycles)


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
    """dram ← counters ← sim ← sources ← calibrate ← daemon ← {tui, cli}: ``package`` imports only lower tiers."""
    upward = [
        f"{e}  [tier {TIERS[package]} -> tier {TIERS.get(area(e.target))}]"
        for e in edges
        if area(e.source) == package != area(e.target)
        and TIERS[package] <= TIERS.get(area(e.target), 99)
    ]
    assert not upward, f"imports of {package or ROOT} against the layering:\n" + "\n".join(upward)


def function_lengths(src: Path = SRC) -> dict[str, int]:
    """Every function's length in lines (``def`` to its last line) by ``path:qualified name``,
    ``path`` relative to ``src``; nested functions count on their own and inside their parent."""
    lengths: dict[str, int] = {}

    def walk(node: ast.AST, prefix: str, where: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                name = f"{prefix}{child.name}"
                if not isinstance(child, ast.ClassDef):
                    assert child.end_lineno is not None
                    lengths[f"{where}:{name}"] = child.end_lineno - child.lineno + 1
                walk(child, f"{name}.", where)
            else:
                walk(child, prefix, where)

    for path in sorted((src / ROOT).rglob("*.py")):
        walk(parsed(path), "", path.relative_to(src).as_posix())
    return lengths


def test_function_lengths_are_measured_def_to_end_with_qualified_names(tmp_path: Path) -> None:
    """Methods and nested functions are named through their class and parent; a length runs from
    the ``def`` line to the last line of the body."""
    (tmp_path / ROOT).mkdir()
    (tmp_path / ROOT / "m.py").write_text(
        "def f():\n    def g():\n        return 1\n    return g\n"
        'class K:\n    async def h(self):\n        """doc"""\n\n        pass\n'
    )
    assert function_lengths(tmp_path) == {
        f"{ROOT}/m.py:f": 4, f"{ROOT}/m.py:f.g": 2, f"{ROOT}/m.py:K.h": 4,
    }


def test_no_function_passes_the_limit_or_grows_past_its_old_length() -> None:
    """Every function is at most MAX_FUNCTION_LINES long, except the listed ones, which may not grow."""
    too_long = [
        f"{name}: {length} lines (limit {LONG_FUNCTIONS.get(name, MAX_FUNCTION_LINES)})"
        for name, length in sorted(function_lengths().items())
        if length > LONG_FUNCTIONS.get(name, MAX_FUNCTION_LINES)
    ]
    assert not too_long, "functions too long (split them):\n" + "\n".join(too_long)


def test_the_long_function_list_holds_only_what_is_still_long() -> None:
    """An entry of LONG_FUNCTIONS names a function that still exists at exactly its listed length,
    so the list ratchets down as functions are split (growing is the test above's failure)."""
    lengths = function_lengths()
    stale = [
        f"{name}: listed {listed}, now {lengths.get(name, 'gone')}"
        for name, listed in sorted(LONG_FUNCTIONS.items())
        if lengths.get(name, 0) < listed
    ]
    assert not stale, "lower or drop these in LONG_FUNCTIONS (tests/test_layering.py):\n" + "\n".join(stale)


#: The daemon's clients: they speak to a daemon through :mod:`hdeem_watch.wire` only.
CLIENTS = ("tui", "bench", "slurm", "metricq", "report", "cli", "demo")
#: Client modules that may import the daemon: the command that runs one.
RUNS_A_DAEMON = {"hdeem_watch.cli.daemon"}


def test_clients_import_nothing_of_the_daemon(edges: list[Edge]) -> None:
    """Issue #26: TUI, bench, SLURM hooks, MetricQ, report, command line and demo import the wire
    package, never ``hdeem_watch.daemon`` (the command that runs a daemon aside)."""
    into_daemon = [
        str(e) for e in edges
        if area(e.source) in CLIENTS and area(e.target) == "daemon" and e.source not in RUNS_A_DAEMON
    ]
    assert not into_daemon, "clients importing the daemon:\n" + "\n".join(into_daemon)
    assert any(area(e.source) in CLIENTS and area(e.target) == "wire" for e in edges)


#: The most modules ``daemon/`` may hold at its top level (issue #26: it held 37); the rest live in
#: its sub-packages by concept (book, ops, jobs, store, shell, counters).
MAX_DAEMON_TOP_LEVEL = 20
#: Smallest number of modules of one directory sharing a name prefix that makes a family (a
#: sub-package waiting to be cut: ``counter_*``, ``store*``, ``job_*``).
FAMILY_SIZE = 3
#: Families there when the rule came, by directory and prefix with their size then; they may only
#: shrink. ``sources/sim*`` leaves when the simulated node becomes its own package (issue #26).
OLD_FAMILIES: dict[str, int] = {
    "cli/model": 4,
    "dram/command": 3,
    "dram/memspec": 4,
    "dram/trace": 4,
    "report/figures": 3,
    "sources/hdeem": 4,
    "sources/sim": 14,
}


def name_families(src: Path = SRC) -> dict[str, list[str]]:
    """Modules of one directory whose names share the prefix before their first ``_``, by
    ``directory/prefix`` (a module named the prefix itself joins its family), families of
    :data:`FAMILY_SIZE` or more only."""
    families: dict[str, list[str]] = {}
    for directory in sorted({p.parent for p in (src / ROOT).rglob("*.py")}):
        stems = sorted(p.stem for p in directory.glob("*.py") if p.stem != "__init__")
        where = directory.relative_to(src / ROOT).as_posix()
        for prefix in sorted({s.split("_")[0] for s in stems if "_" in s}):
            members = [s for s in stems if s == prefix or s.startswith(prefix + "_")]
            if len(members) >= FAMILY_SIZE:
                families[f"{where}/{prefix}"] = members
    return families


def test_name_families_are_found_per_directory(tmp_path: Path) -> None:
    """``store.py``, ``store_jobs.py`` and ``store_writer.py`` are a family; ``groups.py`` is not
    ``group_*``'s, and two of a prefix are no family."""
    for name in ("store", "store_jobs", "store_writer", "groups", "group_rows", "group_fits", "x_a", "x_b"):
        (tmp_path / ROOT / "pkg").mkdir(parents=True, exist_ok=True)
        (tmp_path / ROOT / "pkg" / f"{name}.py").write_text("")
    assert name_families(tmp_path) == {"pkg/store": ["store", "store_jobs", "store_writer"]}


def test_the_daemon_top_level_stays_small() -> None:
    """Issue #26: ``daemon/`` holds at most MAX_DAEMON_TOP_LEVEL modules at its top level."""
    top = sorted(p.name for p in (SRC / ROOT / "daemon").glob("*.py"))
    assert len(top) <= MAX_DAEMON_TOP_LEVEL, f"daemon/ has {len(top)} top-level modules: {top}"


def test_no_new_family_of_modules_by_name_prefix() -> None:
    """Issue #26: no FAMILY_SIZE modules of one directory share a name prefix (cut a sub-package
    instead); the families there when the rule came may only shrink."""
    grown = [
        f"{where}: {members}"
        for where, members in name_families().items()
        if len(members) > OLD_FAMILIES.get(where, FAMILY_SIZE - 1)
    ]
    assert not grown, "families of modules by name prefix (make a sub-package):\n" + "\n".join(grown)


def test_modules_do_not_repeat_their_package_name() -> None:
    """In a sub-package of the daemon a module's name does not repeat the package's:
    ``store/writer.py``, not ``store/store_writer.py``."""
    repeated = [
        p.relative_to(SRC).as_posix()
        for p in (SRC / ROOT / "daemon").glob("*/*.py")
        if p.stem != "__init__" and p.stem.split("_")[0] in {p.parent.name, p.parent.name.rstrip("s")}
    ]
    assert not repeated, "modules repeating their package's name:\n" + "\n".join(repeated)


def daemon_part(module: str) -> str | None:
    """The sub-package (or top-level module) of ``daemon/`` that ``module`` belongs to."""
    parts = module.split(".")
    if len(parts) < 3 or parts[1] != "daemon":
        return None
    return ".".join(parts[:3])


def test_the_daemon_sub_packages_point_one_way(edges: list[Edge]) -> None:
    """Issue #26: ``book ← counters ← jobs ← store ← ops ← compose ← service``, the shell's
    machinery (workers, control, publisher; it reads only the book) under store and ops: no two
    sub-packages of the daemon import each other, around a loop either."""
    node_of = {m: part for m in module_names() if (part := daemon_part(m)) is not None}
    cycles = find_cycles(edges, node_of)
    assert not cycles, "cycles between the daemon's sub-packages:\n" + "\n".join(
        describe(c, edges, node_of) for c in cycles
    )
