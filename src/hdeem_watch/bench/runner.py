"""Run benchmark kernels on 1..N pinned workers and measure them.

One run (:func:`run_one`) goes through four phases:

1. check: the arrays must fit in the available memory (:class:`InputError` otherwise, before any
   allocation) and should be much larger than the LLC (a warning otherwise);
2. prepare: the kernel's libraries load (OpenBLAS for triad), the workers start, each pins itself
   to its own CPU (``os.sched_setaffinity``), and first-touches its contiguous share of every
   array, so its pages are local to it;
3. measure: for a run sized by time (``seconds``), the workers first run one timed probe pass and
   the pass count becomes ``ceil(seconds / probe)``; then ``on_start`` is called (the daemon
   announcement), the wall-clock window opens, all workers run ``repeat`` passes of the kernel over
   their shares, the window closes and ``on_stop`` is called;
4. report: a :class:`RunResult` with the seconds, line rate and DRAM bandwidth the DRAM model's
   traffic count implies.

Two backends run the workers truly in parallel: ``"thread"`` (numpy releases the GIL in every kernel
loop) and ``"process"`` (forked workers, each with its own share of the arrays in private memory:
no GIL at all). Threads are the default: the passes are single numpy calls, so the GIL is held for
microseconds per pass, and threads start faster (see docs/bench.md for the measurement).

Example:
    >>> result = run_one(RunSpec("copy", 1, 1 << 12, 2))
    >>> result.lines_read_per_pass, result.lines_written_per_pass
    (1024, 512)
"""

from __future__ import annotations

import dataclasses
import math
import multiprocessing as mp
import os
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hdeem_watch import slurm
from hdeem_watch.bench import kernels as K
from hdeem_watch.bench import system
from hdeem_watch.bench.schedule import IDLE_KERNEL, RunSpec, canonical_kernel
from hdeem_watch.errors import InputError

BACKENDS = ("thread", "process")
#: Seconds a run may take to prepare or finish before the runner gives up on its workers.
WORKER_TIMEOUT_S = 3600.0
#: A run sized by time is probed with up to this many passes, or this many seconds of them.
PROBE_ROUNDS = 10
PROBE_S = 0.25
#: A probe round shorter than this gets four times the passes in the next round.
PROBE_ROUND_S = 0.01
#: Most passes a run sized by time may get (what run.start accepts; a probe pass of a few lines
#: can take microseconds).
MAX_TIMED_REPEAT = 1_000_000


def passes_for(seconds: float, probe_s: float) -> int:
    """Passes that fill ``seconds`` when one pass took ``probe_s`` (at least 1).

    Example:
        >>> passes_for(2.0, 0.15), passes_for(2.0, 3.0), passes_for(2.0, 0.0)
        (14, 1, 1000000)
    """
    if probe_s <= 0:
        return MAX_TIMED_REPEAT
    return max(1, min(MAX_TIMED_REPEAT, math.ceil(seconds / probe_s)))


def pass_traffic(kernel: str, elements: int) -> tuple[int, int, str]:
    """Return ``(lines_read, lines_written, origin)`` of one pass over all threads' ranges.

    Uses the DRAM model's ``hdeem_watch.dram.kernels.kernel_traffic`` (origin ``"dram-model"``) when
    it is available, the bench's own count otherwise (origin ``"bench-count"``). The idle kernel
    moves no lines.
    """
    name = canonical_kernel(kernel)
    if name == IDLE_KERNEL:
        return 0, 0, "none"
    try:
        from hdeem_watch.dram.kernels import kernel_traffic
    except ImportError:
        reads, writes = K.local_traffic(name, elements)
        return reads, writes, "bench-count"
    traffic = kernel_traffic(name, int(elements))
    return int(traffic.lines_read), int(traffic.lines_written), "dram-model"


@dataclass(frozen=True)
class RunResult:
    """What one run measured.

    Attributes:
        spec: the run's parameters.
        seconds: duration of the measured window (monotonic clock).
        t_start_ns: wall-clock start of the window (ns since the epoch).
        t_end_ns: wall-clock end of the window.
        lines_per_s: loop iterations per second, one 64-byte line per array each (``repeat ×
            elements/8 / seconds``): the line rate the C benchmark compares.
        dram_bytes_per_s: bytes the DRAM model says move (reads incl. write-allocate, and
            write-backs) per second.
        stream_bytes_per_s: bytes per second as STREAM counts them (each array read or written
            once per iteration, no write-allocate: 2/2/3/3 lines for copy/scale/add/triad), to
            compare with STREAM's figures; below ``dram_bytes_per_s`` where the destination is
            not also a source (copy, scale, add, assign).
        lines_read_per_pass: lines read from DRAM per pass (all threads).
        lines_written_per_pass: lines written back per pass.
        traffic_origin: ``"dram-model"``, ``"bench-count"`` or ``"none"`` (idle).
        cpus: the CPU each worker was pinned to, in worker order.
        worker_affinity: the affinity each worker reported after pinning.
        backend: ``"thread"`` or ``"process"``.
        checksum: the read kernel's sum over the last pass (NaN for the other kernels).
        warnings: messages for the user (e.g. arrays not much larger than the LLC).
        announce: what ``on_start``/``on_stop`` returned (e.g. the daemon's run id and energies).
        arrays: the arrays after the run, only when asked for (``keep_arrays=True``).
    """

    spec: RunSpec
    seconds: float
    t_start_ns: int
    t_end_ns: int
    lines_per_s: float
    dram_bytes_per_s: float
    lines_read_per_pass: int
    lines_written_per_pass: int
    traffic_origin: str
    cpus: tuple[int, ...]
    worker_affinity: tuple[tuple[int, ...], ...]
    backend: str
    checksum: float = float("nan")
    warnings: tuple[str, ...] = ()
    announce: Mapping[str, Any] = field(default_factory=dict)
    stream_bytes_per_s: float = 0.0
    arrays: Mapping[str, np.ndarray] | None = field(default=None, repr=False, compare=False)

    def to_dict(self) -> dict[str, Any]:
        """Return the JSON-ready record printed by ``hdeem-watch bench --json``."""
        out: dict[str, Any] = {
            **self.spec.to_dict(),
            "seconds": self.seconds,
            "lines_per_s": self.lines_per_s,
            "dram_bytes_per_s": self.dram_bytes_per_s,
            "stream_bytes_per_s": self.stream_bytes_per_s,
            "lines_read_per_pass": self.lines_read_per_pass,
            "lines_written_per_pass": self.lines_written_per_pass,
            "traffic_origin": self.traffic_origin,
            "t_start_ns": self.t_start_ns,
            "t_end_ns": self.t_end_ns,
            "cpus": list(self.cpus),
            "backend": self.backend,
            "checksum": None if np.isnan(self.checksum) else self.checksum,
        }
        out.update({k: v for k, v in self.announce.items() if k not in out})
        return out


Hook = Callable[[RunSpec], Mapping[str, Any] | None]


@dataclass(frozen=True)
class PlacedRunSpec(RunSpec):
    """A run as the ``on_start``/``on_stop`` hooks see it: the spec and where it was placed.

    A :class:`RunSpec` (hooks that only want the spec keep working); the announcer sends the
    placement to the daemon, which models the run on the sockets it really ran on.

    Attributes:
        cpus: the CPU each worker was pinned to, in worker order.
        array_bytes: bytes of the run's arrays (all of them, all workers).
    """

    cpus: tuple[int, ...] = ()
    array_bytes: int = 0


def choose_cpus(threads: int, allowed: list[int] | None = None, *, oversubscribe: bool = False) -> list[int]:
    """Pick one CPU per worker from the allowed set (socket 0 and physical cores first).

    ``allowed`` defaults to :func:`hdeem_watch.slurm.allowed_cpus`.

    Raises:
        InputError: more threads than allowed CPUs and ``oversubscribe`` is off.
    """
    cpus = system.cpu_order(slurm.allowed_cpus() if allowed is None else allowed)
    if threads > len(cpus) and not oversubscribe:
        raise InputError(f"--threads {threads}: only {len(cpus)} CPUs are allowed here "
                         f"({','.join(map(str, sorted(cpus)))}); expected at most {len(cpus)} "
                         "(or --oversubscribe)")
    return [cpus[i % len(cpus)] for i in range(threads)]


def validate(specs: list[RunSpec], allowed: list[int] | None = None, *, oversubscribe: bool = False,
             available_bytes: int | None = None) -> None:
    """Check a whole schedule before the first run: thread counts and memory of every run.

    Raises:
        InputError: the first run that could not start (so a sweep fails before, not midway).
    """
    for spec in specs:
        kernel = canonical_kernel(spec.kernel)
        choose_cpus(spec.threads, allowed, oversubscribe=oversubscribe)
        system.check_memory(K.array_bytes(kernel, spec.elements),
                            f"--elements {spec.elements} ({kernel}, {len(K.KERNEL_ARRAYS[kernel])} arrays)",
                            available_bytes)


def _worker(kernel: str, arrays: Mapping[str, np.ndarray], lo: int, hi: int, repeat: Any, cpu: int,
            scratch_n: int, ready: Any, go: Any, report: Callable[[tuple[tuple[int, ...], float]], None],
            probe: Any = None, probe_more: Any = None) -> None:
    """One worker: pin, first-touch, [probe passes between pairs of ``probe`` barriers while
    ``probe_more.value``], then ``repeat.value`` passes between ``go`` and the report (``repeat``
    is read after the probe)."""
    os.sched_setaffinity(0, {cpu})
    affinity = tuple(sorted(os.sched_getaffinity(0)))
    K.init_arrays(arrays, lo, hi)
    scratch = np.zeros(scratch_n)
    ready.wait()
    while probe is not None:
        probe.wait()
        if not probe_more.value:
            break
        for _ in range(probe_more.value):
            K.run_pass(kernel, arrays, lo, hi, scratch)
        probe.wait()
    go.wait()
    checksum = 0.0
    for _ in range(repeat.value):
        checksum = K.run_pass(kernel, arrays, lo, hi, scratch)
    report((affinity, checksum))


def run_one(spec: RunSpec, *, backend: str = "thread", allowed: list[int] | None = None,
            oversubscribe: bool = False, on_start: Hook | None = None, on_stop: Hook | None = None,
            keep_arrays: bool = False, available_bytes: int | None = None,
            seconds: float | None = None) -> RunResult:
    """Run one benchmark run and measure it (see the module docstring for the phases).

    Args:
        spec: kernel, threads, elements and repeat.
        backend: ``"thread"`` or ``"process"``.
        allowed: CPUs to use (default: :func:`hdeem_watch.slurm.allowed_cpus`, the affinity mask
            cut to the task's share inside a SLURM allocation).
        oversubscribe: allow more workers than CPUs (round-robin pinning).
        on_start: called with a :class:`PlacedRunSpec` (the spec, the CPUs pinned to, the array
            bytes) after the arrays are ready, just before the window opens; may return a
            mapping stored in ``RunResult.announce`` (e.g. ``{"run_id": ...}``).
        on_stop: called just after the window closes; its mapping is merged into ``announce``.
        keep_arrays: return the arrays in the result (tests check the arithmetic).
        available_bytes: override the available-memory figure (tests).
        seconds: size the run by time: ``spec.repeat`` is replaced by the passes that fill this
            many seconds, after one timed probe pass of all workers (outside the window).

    Raises:
        InputError: unknown backend, too many threads, arrays that do not fit in memory, or
            ``seconds`` not a positive number.
    """
    if backend not in BACKENDS:
        raise InputError(f"--backend {backend!r}: unknown; expected one of {', '.join(BACKENDS)}")
    if seconds is not None and not (math.isfinite(seconds) and seconds > 0):
        raise InputError(f"--seconds {seconds!r}: expected a positive number of seconds")
    kernel = canonical_kernel(spec.kernel)
    spec = RunSpec(kernel, spec.threads, spec.elements, spec.repeat)
    cpus = choose_cpus(spec.threads, allowed, oversubscribe=oversubscribe)
    needed = K.array_bytes(kernel, spec.elements)
    system.check_memory(needed, f"--elements {spec.elements} ({kernel}, {len(K.KERNEL_ARRAYS[kernel])} arrays)",
                        available_bytes)
    warnings = []
    llc = system.llc_total_bytes(sorted(set(cpus)))
    if kernel != IDLE_KERNEL:
        message = system.llc_warning(needed, cpus)
        if message:
            warnings.append(message)
    cores = system.physical_cores()
    if cores is not None and spec.threads > cores:
        warnings.append(f"{spec.threads} threads on {cores} physical cores: workers share cores (SMT)")
    K.prepare(kernel)  # libraries load here, not inside the window (forked workers inherit them)
    scratch_n = K.scratch_size(kernel, K.chunk_lines(llc, spec.threads))
    lines = K.lines_of(spec.elements)
    ranges = K.split_lines(lines, spec.threads)
    runner = _run_threads if backend == "thread" else _run_processes
    announce: dict[str, Any] = {}
    placed = [PlacedRunSpec(kernel, spec.threads, spec.elements, spec.repeat, cpus=tuple(cpus), array_bytes=needed)]

    def start_hook(repeat: int) -> None:
        placed[0] = dataclasses.replace(placed[0], repeat=repeat)
        if on_start is not None:
            announce.update(on_start(placed[0]) or {})

    def stop_hook() -> None:
        if on_stop is not None:
            announce.update(on_stop(placed[0]) or {})

    arrays, t0_ns, t1_ns, elapsed, reports = runner(kernel, spec, cpus, ranges, start_hook, stop_hook,
                                                    keep_arrays, scratch_n, seconds)
    spec = RunSpec(kernel, spec.threads, spec.elements, placed[0].repeat)
    reads, writes, origin = pass_traffic(kernel, spec.elements)
    seconds = max(elapsed, 1e-9)
    return RunResult(
        spec=spec, seconds=seconds, t_start_ns=t0_ns, t_end_ns=t1_ns,
        lines_per_s=0.0 if kernel == IDLE_KERNEL else lines * spec.repeat / seconds,
        dram_bytes_per_s=(reads + writes) * K.LINE_BYTES * spec.repeat / seconds,
        lines_read_per_pass=reads, lines_written_per_pass=writes, traffic_origin=origin,
        cpus=tuple(cpus), worker_affinity=tuple(r[0] for r in reports), backend=backend,
        checksum=float(sum(r[1] for r in reports)) if kernel == "read" else float("nan"),
        warnings=tuple(warnings), announce=announce, arrays=arrays if keep_arrays else None,
        stream_bytes_per_s=K.STREAM_LINES[kernel] * lines * K.LINE_BYTES * spec.repeat / seconds,
    )


def _probe_and_start(start_hook: Callable[[int], None], probe: Any, more: Any, repeat: Any,
                     seconds: float | None, go: Any) -> None:
    """Time the workers' probe passes (when the run is sized by ``seconds``) and set
    ``repeat.value`` from the fastest; then call the start hook with the pass count. If anything
    raises (e.g. the daemon refused the run, or Ctrl-C), release the workers waiting at a barrier
    (it breaks and they end) before the error goes up."""
    try:
        if probe is not None and seconds is not None:
            repeat.value = passes_for(seconds, _probe(probe, more))
        start_hook(int(repeat.value))
    except BaseException:
        if probe is not None:
            probe.abort()
        go.abort()
        raise


def _probe(probe: Any, more: Any) -> float:
    """Seconds of the fastest probe pass: up to :data:`PROBE_ROUNDS` rounds or :data:`PROBE_S` in
    all (a round of short passes runs several, see :data:`PROBE_ROUND_S`). The fastest, because on a shared machine a pass is only ever slowed down (another
    process's time slice), and a pass count from a slowed pass gives a run too short to measure."""
    fastest, spent, rounds, passes = math.inf, 0.0, 0, 1
    while rounds < PROBE_ROUNDS and spent < PROBE_S:
        more.value = passes
        # timed from before the start barrier: a parent descheduled just after it would otherwise
        # start its clock late and time the passes too short (a pass count 60x too high under load)
        m0 = time.perf_counter_ns()
        probe.wait(WORKER_TIMEOUT_S)
        probe.wait(WORKER_TIMEOUT_S)
        took = (time.perf_counter_ns() - m0) / 1e9
        fastest, spent, rounds = min(fastest, took / passes), spent + took, rounds + 1
        if took < PROBE_ROUND_S:  # short passes: more per round, so the barriers' latency does not count
            passes = min(passes * 4, MAX_TIMED_REPEAT)
    more.value = 0
    probe.wait(WORKER_TIMEOUT_S)  # the workers see 0 and go on to ``go``
    return fastest


class _Passes:
    """A number the thread workers read (``.value``, like ``mp.Value``): the pass count, or
    whether another probe pass follows."""

    def __init__(self, value: int) -> None:
        self.value = value


_Outcome = tuple[dict[str, np.ndarray], int, int, float, list[tuple[tuple[int, ...], float]]]


def _run_threads(kernel: str, spec: RunSpec, cpus: list[int], ranges: list[tuple[int, int]],
                 start_hook: Callable[[int], None], stop_hook: Callable[[], None], keep: bool,
                 scratch_n: int, seconds: float | None) -> _Outcome:
    arrays = K.make_arrays(kernel, spec.elements)
    n = spec.threads
    ready, go = threading.Barrier(n + 1), threading.Barrier(n + 1)
    probe = threading.Barrier(n + 1) if seconds is not None else None
    repeat, more = _Passes(spec.repeat), _Passes(0)
    reports: list[Any] = [None] * n
    errors: list[BaseException] = []

    def body(i: int) -> None:
        try:
            _worker(kernel, arrays, *ranges[i], repeat, cpus[i], scratch_n, ready, go,
                    lambda r: reports.__setitem__(i, r), probe, more)
        except BaseException as error:  # surfaced below; the barriers must not hang
            errors.append(error)
            ready.abort()
            if probe is not None:
                probe.abort()
            go.abort()

    workers = [threading.Thread(target=body, args=(i,), name=f"bench-{i}", daemon=True) for i in range(n)]
    for worker in workers:
        worker.start()
    try:
        ready.wait(WORKER_TIMEOUT_S)
        _probe_and_start(start_hook, probe, more, repeat, seconds, go)
        t0_ns, m0 = time.time_ns(), time.perf_counter_ns()
        go.wait(WORKER_TIMEOUT_S)
        for worker in workers:
            worker.join()
        m1, t1_ns = time.perf_counter_ns(), time.time_ns()
    except threading.BrokenBarrierError:
        for worker in workers:
            worker.join(1.0)
        raise RuntimeError(f"bench worker failed: {errors[0] if errors else 'timeout'}") from None
    if errors:
        raise RuntimeError(f"bench worker failed: {errors[0]}")
    stop_hook()
    return arrays, t0_ns, t1_ns, (m1 - m0) / 1e9, reports


def _run_processes(kernel: str, spec: RunSpec, cpus: list[int], ranges: list[tuple[int, int]],
                   start_hook: Callable[[int], None], stop_hook: Callable[[], None], keep: bool,
                   scratch_n: int, seconds: float | None) -> _Outcome:
    """Forked workers, each allocating and first-touching only its own share, privately.

    Nothing is shared: the parent never reads the arrays during a run, so each worker's share is
    ordinary process memory (numpy asks for transparent huge pages; shared anonymous memory would
    be shmem, which gets none unless ``shmem_enabled`` allows it). With ``keep`` the shares are
    sent back after the window and joined.
    """
    ctx = mp.get_context("fork")
    n = spec.threads
    ready, go = ctx.Barrier(n + 1), ctx.Barrier(n + 1)
    probe = ctx.Barrier(n + 1) if seconds is not None else None
    repeat, more = ctx.Value("q", spec.repeat, lock=False), ctx.Value("q", 0, lock=False)
    pipes = [ctx.Pipe(duplex=False) for _ in range(n)]

    def body(i: int) -> None:
        send = pipes[i][1]
        lo, hi = ranges[i]
        try:
            local = K.make_arrays(kernel, max(0, min(hi * 8, spec.elements) - lo * 8))
            _worker(kernel, local, 0, hi - lo, repeat, cpus[i], scratch_n, ready, go, send.send, probe, more)
            if keep:
                send.send(local)
        except BaseException:
            ready.abort()
            if probe is not None:
                probe.abort()
            go.abort()
            raise
        finally:
            send.close()

    procs = [ctx.Process(target=body, args=(i,), daemon=True) for i in range(n)]
    for proc in procs:
        proc.start()
    for _, send in pipes:
        send.close()  # the parent keeps only the read ends: a dead worker reads as EOF
    out: dict[str, np.ndarray] = {}
    try:
        ready.wait(WORKER_TIMEOUT_S)
        _probe_and_start(start_hook, probe, more, repeat, seconds, go)
        t0_ns, m0 = time.time_ns(), time.perf_counter_ns()
        go.wait(WORKER_TIMEOUT_S)
        reports = [recv.recv() for recv, _ in pipes]
        m1, t1_ns = time.perf_counter_ns(), time.time_ns()
        if keep:
            shares = [recv.recv() for recv, _ in pipes]
            out = {name: np.concatenate([share[name] for share in shares]) for name in K.KERNEL_ARRAYS[kernel]}
    except (threading.BrokenBarrierError, EOFError):
        raise RuntimeError("bench worker process failed") from None
    finally:
        for proc in procs:
            proc.join(5.0)
            if proc.is_alive():
                proc.kill()
        for recv, _ in pipes:
            recv.close()
    stop_hook()
    return out, t0_ns, t1_ns, (m1 - m0) / 1e9, reports
