"""Fixtures shared by every test package, and the guard that keeps the fast loop fast.

The guard: a test not marked ``slow`` fails if it starts a process (any ``subprocess``, ``fork``,
``posix_spawn``, ``system`` or ``exec``, seen through the interpreter's audit hooks, PEP 578) or if
test code (a file under ``tests/``) calls ``time.sleep`` — in its setup or its body, on its own
thread or one it started — or if it carries a mark of an external program (``slurm``,
``tmux``) without ``slow``. So ``pytest -m "not slow"`` runs no daemon, terminal, broker, browser,
SLURM or timed wait. The only processes it allows are the compilers of :data:`BUILD_FIXTURES`,
which build the C test doubles once per session.
"""

from __future__ import annotations

import fcntl
import hashlib
import importlib.util
import os
import shutil
import signal
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Generator, Iterator
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path
from typing import Any

import pytest

#: Compiled test modules are cached even where ``PYTHONDONTWRITEBYTECODE`` is set (as on the CI
#: machine): without the cache every xdist worker parses and assertion-rewrites all ~560 test
#: modules and compiles ``src/`` again on every run — 8 s of each worker's collection, 2 s with it.
#: The cache is ``__pycache__/`` (git-ignored); the environment of subprocesses is left as it is.
sys.dont_write_bytecode = False


class FakeClock:
    """A monotonic clock in integer nanoseconds that moves only when a test moves it.

    Example:
        >>> clock = FakeClock(1_000)
        >>> clock.t += 500
        >>> clock()
        1500
    """

    def __init__(self, start_ns: int = 0) -> None:
        self.t = start_ns

    def __call__(self) -> int:
        return self.t


@pytest.fixture
def fake_clock() -> Callable[..., FakeClock]:
    """Make fake clocks: ``clock = fake_clock()`` (starts at 0 ns) or ``fake_clock(start_ns)``;
    pass ``clock`` where a ``clock=`` is injected and set or advance ``clock.t`` (ns)."""
    return FakeClock


@contextmanager
def _serving(server: Any, poll_ms: int = 10) -> Iterator[None]:
    """Answer ``server``'s requests (a :class:`~hdeem_watch.daemon.shell.control.ControlServer`) on a
    thread while the block runs, as the daemon's loop would."""
    halt = threading.Event()

    def serve() -> None:
        while not halt.is_set():
            if server.socket.poll(poll_ms):
                server.handle()

    thread = threading.Thread(target=serve, name="serve-control")
    thread.start()
    try:
        yield
    finally:
        halt.set()
        thread.join()


@pytest.fixture
def serve_control() -> Callable[..., AbstractContextManager[None]]:
    """``with serve_control(server): ...`` answers a ControlServer's requests on a thread meanwhile."""
    return _serving


def _build_trees(generator: str, dest: Path) -> Path:
    """Run ``build(dest)`` of a fixture-tree generator module (a file under tests/)."""
    path = Path(__file__).resolve().parent / generator
    spec = importlib.util.spec_from_file_location(f"_trees_{path.stem}", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return Path(module.build(dest))


def _trees(config: pytest.Config, generator: str, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The trees of a generator (a file under tests/, standard library only), built at test time
    once for its source: in pytest's cache directory under the hash of the generator, shared by
    the workers and by later runs (the trees are read-only to the tests; a test that changes one
    copies it first). The first worker builds them under a lock while the others wait. Without a
    cache directory (``-p no:cacheprovider``, a read-only clone), every worker builds its own under
    its temporary directory."""
    key = hashlib.sha256((Path(__file__).resolve().parent / generator).read_bytes()).hexdigest()[:16]
    name = Path(generator).stem
    cache = getattr(config, "cache", None)
    try:
        root = Path(cache.mkdir(f"trees-{name}")) if cache is not None else None
    except OSError:
        root = None
    if root is None:
        return _build_trees(generator, tmp_path_factory.mktemp(name))
    final = root / key
    with open(root / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # one worker builds, the others wait for its trees
        if not final.is_dir():
            staging = Path(tempfile.mkdtemp(prefix=".build-", dir=root))
            try:
                _build_trees(generator, staging / "trees")
                os.rename(staging / "trees", final)  # whole trees or none (a build cut short leaves none)
            finally:
                shutil.rmtree(staging, ignore_errors=True)
            for stale in root.iterdir():  # the trees of an older generator
                if stale.name not in (key, ".lock"):
                    shutil.rmtree(stale, ignore_errors=True)
    return final


@pytest.fixture
def build_trees() -> Callable[[str, Path], Path]:
    """``build_trees(generator, dest)``: a fresh build of a generator's trees (test modules cannot
    import conftest in importlib mode)."""
    return _build_trees


@pytest.fixture(scope="session")
def node_trees(pytestconfig: pytest.Config, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The node fixtures (``<node>/sys``, ``<node>/dmidecode.txt``), built by tests/node/make_fixtures.py."""
    return _trees(pytestconfig, "node/make_fixtures.py", tmp_path_factory)


@pytest.fixture(scope="session")
def pmu_trees(pytestconfig: pytest.Config, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The perf PMU trees (``sysfs_<host>/bus/event_source/devices``), built by tests/counters/pmu_trees.py."""
    return _trees(pytestconfig, "counters/pmu_trees.py", tmp_path_factory)


@pytest.fixture(scope="session")
def powercap_trees(pytestconfig: pytest.Config, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The powercap and perf ``power`` trees, built by tests/sources/powercap_trees.py (tests that
    write counters copy a tree first, with ``symlinks=True``)."""
    return _trees(pytestconfig, "sources/powercap_trees.py", tmp_path_factory)


#: Audit events (PEP 578) raised when a process is started.
PROCESS_EVENTS = frozenset({"subprocess.Popen", "os.fork", "os.forkpty", "os.posix_spawn",
                            "os.spawn", "os.system", "os.exec"})
#: Marks of an external program under test: such a test is slow by definition.
EXTERNAL_MARKS = ("slurm", "tmux")
#: Session fixtures that compile C test doubles (gcc) once: a build step, not a process under test.
BUILD_FIXTURES = frozenset({"fake_hdeem_build", "standin_build"})
#: Sleeps called from files under here are the tests' own waits.
TESTS_DIR = str(Path(__file__).resolve().parent) + os.sep


class SlowGuard:
    """What a test not marked ``slow`` did that only slow tests may do (a process, a sleep)."""

    def __init__(self) -> None:
        self.active = False
        self.found: list[str] = []
        self.processes_started = 0
        #: Fixtures (of any scope) whose setup started a process: a test using one is slow even
        #: where the process was started for an earlier test (a session's shared daemon).
        self.process_fixtures: set[str] = set()
        self._threads_before: set[threading.Thread] = set()
        self._sleep = time.sleep

    def audit(self, event: str, args: tuple[Any, ...]) -> None:
        """The audit hook (installed once, for the session; it records only while a test is guarded)."""
        if event in PROCESS_EVENTS:
            self.processes_started += 1
            if self.active:
                self.found.append(f"started a process ({event} {str(args[0])[:80] if args else ''})")

    def _guarded_sleep(self, seconds: float) -> None:
        thread = threading.current_thread()
        if (self.active and sys._getframe(1).f_code.co_filename.startswith(TESTS_DIR)
                and (thread is threading.main_thread() or thread not in self._threads_before)):
            self.found.append(f"slept {seconds} s on thread {thread.name!r}")
        self._sleep(seconds)

    def start(self) -> None:
        """Watch from now on (threads already running, e.g. left by an earlier test, are not watched)."""
        self.active, self.found = True, []
        self._threads_before = set(threading.enumerate()) - {threading.main_thread()}
        time.sleep = self._guarded_sleep

    def stop(self) -> None:
        self.active = False
        time.sleep = self._sleep

    def check(self, item: pytest.Item, phase: str) -> None:
        """Fail ``item`` if it did anything reserved for slow tests (each kind named once)."""
        if self.active and phase == "setup":
            fixtures = sorted(self.process_fixtures & set(getattr(item, "fixturenames", ())))
            self.found += [f"uses the fixture {name!r}, which started a process" for name in fixtures]
        if self.active and self.found:
            seen = list(dict.fromkeys(self.found))
            self.found = []
            pytest.fail(f"{item.nodeid} is not marked slow but in its {phase} it "
                        + "; ".join(seen[:3]) + ": mark it @pytest.mark.slow (tests/conftest.py)", pytrace=False)


_guard = SlowGuard()
sys.addaudithook(_guard.audit)


@pytest.fixture
def slow_guard() -> SlowGuard:
    """The session's guard (for the guard's own tests)."""
    return _guard


class _FixtureWatch:
    """Notes the fixtures that start processes, and sets up :data:`BUILD_FIXTURES` with the guard
    paused. A plugin of its own: a conftest's hooks see only the nodes below its directory, and a
    session fixture is set up by the session's node."""

    @pytest.hookimpl(wrapper=True)
    def pytest_fixture_setup(self, fixturedef: pytest.FixtureDef[Any]) -> Generator[Any, None, Any]:
        if fixturedef.argname in BUILD_FIXTURES:
            watching, _guard.active = _guard.active, False
            try:
                return (yield)
            finally:
                _guard.active = watching
        before = _guard.processes_started
        try:
            return (yield)
        finally:
            if _guard.processes_started > before:
                _guard.process_fixtures.add(fixturedef.argname)


def pytest_configure(config: pytest.Config) -> None:
    config.pluginmanager.register(_FixtureWatch(), "hdeem-watch-fixture-watch")


def _interruptible() -> None:
    """SIGINT handled as Python's default in this process, so the processes a test starts react to
    Ctrl-C (``send_signal(SIGINT)``) as under a terminal. An ignored SIGINT is inherited through exec
    and a Python child then keeps ignoring it: a leak of ``SIG_IGN`` from one test (or library) made
    every later Ctrl-C test of the same xdist worker hang."""
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_setup(item: pytest.Item) -> Generator[None, None, None]:
    _interruptible()
    if item.get_closest_marker("slow") is None:
        external = [m for m in EXTERNAL_MARKS if item.get_closest_marker(m) is not None]
        if external:
            pytest.fail(f"{item.nodeid} is marked {external[0]} but not slow: mark it @pytest.mark.slow",
                        pytrace=False)
        _guard.start()
    yield
    _guard.check(item, "setup")


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item: pytest.Item) -> Generator[None, None, None]:
    yield
    _guard.check(item, "body")


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_teardown(item: pytest.Item, nextitem: pytest.Item | None) -> None:
    """Teardowns are not watched: a wider fixture's teardown (the session's SLURM) runs in the last
    test's, and a function fixture that starts a process has done so in its setup."""
    _guard.stop()


#: The tests that take longest (10-40 s each on the CI machine, measured with ``--durations``), by
#: node-id prefix. They are handed out first so that the end of a ``-n 4`` run is short tests on all
#: workers: the run lasts as long as its busiest worker, and a 40 s test started last would leave the
#: others idle. Only the order changes (xdist's loadgroup sends the groups first, then single tests in
#: this order); a test missing here just runs in its place.
LONG_TESTS_FIRST = (
    "tests/demo/test_sim_runs.py::",
    "tests/bench/test_daemon_announce.py::test_default_runs",
    "tests/test_packaging.py::test_the_wheel",
    "tests/tui/test_demo_aging.py::",
    "tests/report/test_cli_report.py::test_demo_headless_with_report",
    "tests/tui/test_demo_lifecycle.py::test_the_log_is_kept",
    "tests/tui/test_demo.py::test_demo_design_determines",
    "tests/daemon/test_quiet_polling.py::",
    "tests/daemon/test_physical_rules_modeller.py::",
    "tests/dram/test_kernels.py::test_streams_reproduce_reference_trace_hashes",
    "tests/tui/test_groups_tmux.py::",
    "tests/tui/test_demo.py::test_demo_in_a_real_terminal",
    "tests/slurm/test_hooks.py::",
)


def long_first_rank(nodeid: str) -> int:
    """The place of ``nodeid`` in :data:`LONG_TESTS_FIRST` (its length for any other test).

    Example:
        >>> long_first_rank("tests/demo/test_sim_runs.py::test_x"), long_first_rank("tests/test_cli.py::test_y")
        (0, 13)
    """
    return next((i for i, prefix in enumerate(LONG_TESTS_FIRST) if nodeid.startswith(prefix)), len(LONG_TESTS_FIRST))


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The long tests first (:data:`LONG_TESTS_FIRST`), every other test in its collected order."""
    items.sort(key=lambda item: long_first_rank(item.nodeid))
