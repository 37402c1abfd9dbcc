"""Bench kernels vs the same stride-8 loops in C (gcc -O2, pthreads, same pinned CPUs).

Target (DESIGN.md §8): each hdeem-watch kernel reaches >= 90 % of the line rate of the C loop with
the same thread count. The C program is written and built by this script; both sides use the same
arrays size, repeat count, CPU pinning, first touch by the worker, page size (transparent huge
pages via ``madvise``, which numpy requests for large arrays) and timing method (all workers ready,
window opens, ``repeat`` passes, all workers done). Runs of C and hdeem-watch alternate one by one
(C, hw, C, hw, ...) so a change of machine load or memory state hits both alike.

SUMMARY, the same on both sides: the **median of every run**. C has one side per build (8
placements, below) and hdeem-watch as many slots; all run once per trial, in rotating order, for
``--trials`` trials, and the whole table is measured ``--sweeps`` times (default 2: each row is
sampled minutes apart, so a slow change of the machine's state averages out instead of deciding a
row). A row compares the median over all of hdeem-watch's runs (sweeps x slots x trials) with the
median over all of C's runs (sweeps x builds x trials). This VM's memory has a fast state that
comes and goes for seconds at a time and catches 10-20 % of the runs, C and numpy alike (2
threads, selfscale: C runs at 417 Mlines/s median and 641-673 in its top 3 of 40; numpy 409 and
577-677). A best-of-N figure per side took the fast state or not at random, and the median of
eight such figures swung with it: read at 2 threads read 1.55 and 1.30 of C in two consecutive
runs at stop 11. The median of all runs is the typical state on both sides and does
not swing. The 90th percentiles are printed beside it (the fast state, ``/p90``), and the median
of the fastest placement (``/best``).

PLACEMENTS. On the AMD EPYC (Zen) machine this was built on, the line rate of a stride-64-byte
loop depends on where the loop's ~20-30 bytes of code sit in their 64-byte code line: the very same
gcc -O2 triad loop runs at 191-200 Mlines/s when it crosses a 64-byte boundary and at 141-167 when
it does not (median of 8 runs each, 1 thread; docs/performance.md). gcc places a loop wherever the
surrounding code leaves it, so one build measures an accident of placement as much as the loop.
The C program is therefore built eight times, its loops moved by 8 bytes each time (``PAD`` bytes
of no-ops at the start of each kernel function), which puts each loop at each of the eight 8-byte
places of a 64-byte line; the baseline is the median over all their runs, and the fastest build's
median is printed beside it (``C best``) with the ratio to it. numpy's loops are compiled once, in the
wheel, at whatever places they have.

Usage::

    python3 benchmarks/bench_kernels_vs_c.py            # 2**25 doubles/array, repeat 2, 2 sweeps x 4 trials
    python3 benchmarks/bench_kernels_vs_c.py --quick    # 2**24, repeat 2, 1 sweep x 3 trials, 4 placements
    python3 benchmarks/bench_kernels_vs_c.py --backend both   # threads and processes side by side

Short windows and many alternating trials, because a shared machine preempts long windows: a
preempted short window is one outlier among 64 runs, below the median.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import os
import statistics
import subprocess
import sys
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from hdeem_watch.bench import kernels as K
from hdeem_watch.bench.runner import choose_cpus, run_one
from hdeem_watch.bench.schedule import KERNELS, RunSpec
from hdeem_watch.bench.system import llc_total_bytes

TARGET = 0.90

#: Bytes of no-ops in front of each C loop, one build each: every loop lands once on each of the
#: eight 8-byte places of a 64-byte code line (see PLACEMENTS in the module doc).
PLACEMENT_PADS = (0, 8, 16, 24, 32, 40, 48, 56)

C_SOURCE = r"""
#define _GNU_SOURCE
#include <pthread.h>
#include <sched.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <time.h>

#ifndef PAD
#define PAD 0
#endif
#define STR_(x) #x
#define STR(x) STR_(x)
/* Each kernel is its own 64-byte-aligned function that starts with PAD bytes of no-ops: the
   loop's place inside a 64-byte code line moves with PAD (and nothing else does). */
#define KERNEL(name, body) \
    __attribute__((noinline, aligned(64))) static double name(long lo, long hi) { \
        __asm__ volatile(".fill " STR(PAD) ", 1, 0x90"); \
        double sum = 0.0; \
        for (long k = lo * 8; k < hi * 8; k += 8) body \
        return sum; \
    }

static double *a, *b, *c;
static long lines, repeat;
static int threads, kernel;
static int cpus[1024];
static double sums[1024];
static pthread_barrier_t ready, go;

KERNEL(k_read, sum += a[k];)
KERNEL(k_assign, a[k] = 2.0;)
KERNEL(k_scale, b[k] = 2.0 * a[k];)
KERNEL(k_add, c[k] = a[k] + b[k];)
KERNEL(k_triad, a[k] = b[k] + 2.0 * a[k];)
KERNEL(k_copy, b[k] = a[k];)
KERNEL(k_selfscale, a[k] = 2.0 * a[k];)
static double (*const kernels[])(long, long) = {k_read, k_assign, k_scale, k_add, k_triad, k_copy, k_selfscale};

/* 2 MiB-aligned and advised for transparent huge pages, as numpy does for large arrays. */
static double *alloc(long n) {
    void *p = NULL;
    if (posix_memalign(&p, 1 << 21, n * 8)) return NULL;
    madvise(p, n * 8, MADV_HUGEPAGE);
    return p;
}

static double now(void) { struct timespec t; clock_gettime(CLOCK_MONOTONIC, &t); return t.tv_sec + 1e-9 * t.tv_nsec; }

static void *worker(void *arg) {
    long w = (long)arg;
    cpu_set_t set; CPU_ZERO(&set); CPU_SET(cpus[w], &set);
    pthread_setaffinity_np(pthread_self(), sizeof set, &set);
    long base = lines / threads, extra = lines % threads;
    long lo = w * base + (w < extra ? w : extra), hi = lo + base + (w < extra ? 1 : 0);
    for (long i = lo * 8; i < hi * 8; i++) { a[i] = 1.0; if (b) b[i] = 2.0; if (c) c[i] = 0.0; }
    pthread_barrier_wait(&ready);
    pthread_barrier_wait(&go);
    double sum = 0.0;
    for (long r = 0; r < repeat; r++) sum = kernels[kernel](lo, hi);
    sums[w] = sum;
    return NULL;
}

int main(int argc, char **argv) {
    /* kernel elements repeat trials cpu0,cpu1,... */
    static const char *names[] = {"read", "assign", "scale", "add", "triad", "copy", "selfscale"};
    for (kernel = 0; kernel < 7 && strcmp(names[kernel], argv[1]); kernel++) {}
    long elements = atol(argv[2]); repeat = atol(argv[3]); int trials = atoi(argv[4]);
    threads = 0;
    for (char *p = strtok(argv[5], ","); p; p = strtok(NULL, ",")) cpus[threads++] = atoi(p);
    lines = (elements + 7) / 8;
    int narrays = (kernel == 3) ? 3 : (kernel == 2 || kernel == 4 || kernel == 5) ? 2 : 1;
    double best = 1e30, check = 0.0;
    for (int t = 0; t < trials; t++) {
        a = alloc(elements); b = narrays > 1 ? alloc(elements) : NULL;
        c = narrays > 2 ? alloc(elements) : NULL;
        pthread_barrier_init(&ready, NULL, threads + 1); pthread_barrier_init(&go, NULL, threads + 1);
        pthread_t tid[1024];
        for (long w = 0; w < threads; w++) pthread_create(&tid[w], NULL, worker, (void *)w);
        pthread_barrier_wait(&ready);
        double t0 = now();
        pthread_barrier_wait(&go);
        for (int w = 0; w < threads; w++) pthread_join(tid[w], NULL);
        double dt = now() - t0;
        if (dt < best) best = dt;
        check = 0.0;
        for (int w = 0; w < threads; w++) check += sums[w];
        for (long k = 0; k < elements; k += 8 * 4099) check += a[k] + (b ? b[k] : 0) + (c ? c[k] : 0);
        free(a); free(b); free(c);
        pthread_barrier_destroy(&ready); pthread_barrier_destroy(&go);
    }
    printf("%.9f %g\n", best, check);
    return 0;
}
"""


#: The loop statements of the standalone program, reused verbatim for the in-process library.
LOOP_BODIES = {
    "read": "sum += a[k];", "assign": "a[k] = 2.0;", "scale": "b[k] = 2.0 * a[k];",
    "add": "c[k] = a[k] + b[k];", "triad": "a[k] = b[k] + 2.0 * a[k];", "copy": "b[k] = a[k];",
    "selfscale": "a[k] = 2.0 * a[k];",
}
LIB_SOURCE = "".join(
    f"double k_{name}(double *a, double *b, double *c, long lo, long hi) {{\n"
    f"    double sum = 0.0;\n    for (long k = lo * 8; k < hi * 8; k += 8) {body}\n    return sum;\n}}\n"
    for name, body in LOOP_BODIES.items())


def build(workdir: Path, pad: int = 0) -> Path:
    """Write and compile the C loops with gcc -O2 -pthread, each loop moved by ``pad`` bytes."""
    for name, body in LOOP_BODIES.items():  # the program's kernels hold the same statements
        assert f"KERNEL(k_{name}, {body})" in C_SOURCE, name
    source = workdir / "stride8.c"
    source.write_text(C_SOURCE)
    exe = workdir / f"stride8-pad{pad}"
    subprocess.run(["gcc", "-O2", "-pthread", f"-DPAD={int(pad)}", "-o", str(exe), str(source)], check=True)
    return exe


def build_lib(workdir: Path) -> ctypes.CDLL:
    """Compile the same loops as a shared library (gcc -O2) for the in-process column."""
    source = workdir / "stride8lib.c"
    source.write_text(LIB_SOURCE)
    lib = workdir / "libstride8.so"
    subprocess.run(["gcc", "-O2", "-shared", "-fPIC", "-o", str(lib), str(source)], check=True)
    dll = ctypes.CDLL(str(lib))
    for name in LOOP_BODIES:
        fn = getattr(dll, f"k_{name}")
        fn.restype = ctypes.c_double
        fn.argtypes = [ctypes.c_void_p] * 3 + [ctypes.c_long] * 2
    return dll


def c_in_runner(dll: ctypes.CDLL) -> Callable[..., float]:
    """A drop-in for ``kernels.run_pass`` that runs the C loop (ctypes releases the GIL)."""

    def run_pass(kernel: str, arrays: dict[str, np.ndarray], lo: int, hi: int, scratch: np.ndarray) -> float:
        ptrs = [arrays[n].ctypes.data if n in arrays else None for n in ("a", "b", "c")]
        return float(getattr(dll, f"k_{kernel}")(*ptrs, lo, hi))

    return run_pass


def c_seconds(exe: Path, kernel: str, elements: int, repeat: int, trials: int, cpus: list[int]) -> float:
    """Best wall time of ``repeat`` passes of the C loop."""
    out = subprocess.run([str(exe), kernel, str(elements), str(repeat), str(trials),
                          ",".join(map(str, cpus))], capture_output=True, text=True, check=True).stdout
    return float(out.split()[0])


@contextlib.contextmanager
def patched_run_pass(replacement: Callable[..., float] | None) -> Iterator[None]:
    """Temporarily run another pass function inside the hdeem-watch runner."""
    original = K.run_pass
    if replacement is not None:
        K.run_pass = replacement  # type: ignore[assignment]
    try:
        yield
    finally:
        K.run_pass = original  # type: ignore[assignment]


def py_seconds(kernel: str, threads: int, elements: int, repeat: int, backend: str,
               run_pass: Callable[..., float] | None = None) -> float:
    """Wall time of ``repeat`` passes in the hdeem-watch runner (its kernel, or ``run_pass``)."""
    with patched_run_pass(run_pass):
        return run_one(RunSpec(kernel, threads, elements, repeat), backend=backend).seconds


def all_rates(exes: dict[int, Path], kernel: str, threads: int, elements: int, repeat: int, trials: int,
              backends: list[str], c_pass: Callable[..., float] | None = None) -> dict[str, list[float]]:
    """Line rates of every run of every C placement and of as many slots per backend, trials rotating.

    Keys: ``"c@<pad>"`` per C build, ``"<backend>#<k>"`` for each backend's slots (one slot per C
    build, so both sides run equally often), and ``"c-in-runner"`` when ``c_pass`` is given.
    """
    cpus = choose_cpus(threads)
    lines = (elements + 7) // 8
    # C and hdeem-watch alternate run by run (c@0, thread#0, c@8, thread#1, ...), so a change of the
    # machine's state lasting a few runs hits both sides alike.
    sides = [side for k, pad in enumerate(exes)
             for side in [f"c@{pad}"] + [f"{backend}#{k}" for backend in backends]]
    sides += ["c-in-runner"] if c_pass else []
    rates: dict[str, list[float]] = {side: [] for side in sides}
    for trial in range(trials):
        shift = trial % len(sides)
        for side in sides[shift:] + sides[:shift]:
            if side.startswith("c@"):
                seconds = c_seconds(exes[int(side[2:])], kernel, elements, repeat, 1, cpus)
            elif side == "c-in-runner":
                seconds = py_seconds(kernel, threads, elements, repeat, "thread", c_pass)
            else:
                seconds = py_seconds(kernel, threads, elements, repeat, side.split("#")[0])
            rates[side].append(lines * repeat / seconds)
    return rates


def pooled(rates: dict[str, list[float]], prefix: str) -> list[float]:
    """Every run of the sides whose key starts with ``prefix`` (all C builds, or one backend's slots)."""
    return [rate for side, runs in rates.items() if side.startswith(prefix) for rate in runs]


def c_summary(rates: dict[str, list[float]], pads: list[int]) -> tuple[float, float, float, float]:
    """``(slowest placement, median of all runs, fastest placement, 90th percentile)`` of C.

    A placement's figure is the median of its own runs.

    Example:
        >>> c_summary({"c@0": [1.0, 2.0, 3.0], "c@8": [4.0, 5.0, 9.0]}, [0, 8])
        (2.0, 3.5, 5.0, 7.0)
    """
    per_build = [float(statistics.median(rates[f"c@{pad}"])) for pad in pads]
    runs = pooled(rates, "c@")
    return min(per_build), float(statistics.median(runs)), max(per_build), float(np.quantile(runs, 0.9))


def main(argv: list[str] | None = None) -> int:
    """Run the comparison and print one row per kernel and thread count."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller arrays, fewer passes, trials and placements")
    parser.add_argument("--elements", type=int, help="doubles per array (default 2**25, quick 2**24)")
    parser.add_argument("--repeat", type=int, help="passes per run (default 2)")
    parser.add_argument("--trials", type=int, help="runs of each build and slot per sweep (default 4, quick 3)")
    parser.add_argument("--sweeps", type=int, help="times the whole table is measured, runs pooled (default 2, quick 1)")
    parser.add_argument("--threads", default=None, help="comma-separated thread counts (default 1 and all CPUs)")
    parser.add_argument("--kernels", default=",".join(KERNELS))
    parser.add_argument("--placements", default=None,
                        help="comma-separated pads (bytes) of the C builds (default 0,8,...,56; quick 0,16,32,48)")
    parser.add_argument("--backend", default="thread", choices=("thread", "process", "both"),
                        help="hdeem-watch worker backend; 'both' measures threads and processes side by side")
    parser.add_argument("--c-in-runner", action="store_true",
                        help="add a column: the same C loops (ctypes) run inside the hdeem-watch runner, "
                             "to separate loop speed from process effects")
    args = parser.parse_args(argv)
    elements = args.elements or (1 << 24 if args.quick else 1 << 25)
    repeat = args.repeat or 2
    trials = args.trials or (3 if args.quick else 4)
    sweeps = args.sweeps or (1 if args.quick else 2)
    pads = ([int(p) for p in args.placements.split(",")] if args.placements
            else list(PLACEMENT_PADS[::2] if args.quick else PLACEMENT_PADS))
    backends = ["thread", "process"] if args.backend == "both" else [args.backend]
    ncpu = len(os.sched_getaffinity(0))
    counts = [int(t) for t in args.threads.split(",")] if args.threads else sorted({1, ncpu})
    llc = llc_total_bytes(sorted(os.sched_getaffinity(0)))
    print(f"arrays: {elements} doubles = {elements * 8 / 2**20:.0f} MiB each; LLC "
          f"{(llc or 0) / 2**20:.0f} MiB; repeat {repeat}; {sweeps} sweeps x {trials} trials; C built at {len(pads)} "
          f"loop placements, hdeem-watch in {len(pads)} slots; medians of all {sweeps * trials * len(pads)} runs "
          "per side compared; "
          f"load average {os.getloadavg()[0]:.2f}")
    header = f"{'kernel':<10}{'threads':>8}{'C slowest':>10}{'C median':>10}{'C best':>8}{'C p90':>8}"
    for backend in backends:
        header += f"{backend:>9}{'/median':>8}{'/best':>6}{'/p90':>6}"
    if args.c_in_runner:
        header += f"{'C-in-runner':>12}{'/median':>8}"
    print(f"{header}  (Mlines/s; target >= {TARGET:.0%} of the C median)")
    worst = dict.fromkeys(backends, float("inf"))
    worst_best = dict.fromkeys(backends, float("inf"))
    with tempfile.TemporaryDirectory(prefix="bench-c-") as tmp:
        exes = {pad: build(Path(tmp), pad) for pad in pads}
        c_pass = c_in_runner(build_lib(Path(tmp))) if args.c_in_runner else None
        rows = [(kernel, threads) for kernel in args.kernels.split(",") for threads in counts]
        table: dict[tuple[str, int], dict[str, list[float]]] = {row: {} for row in rows}
        for sweep in range(sweeps):
            for kernel, threads in rows:
                print(f"sweep {sweep + 1}/{sweeps}: {kernel} x {threads}", file=sys.stderr, flush=True)
                runs = all_rates(exes, kernel, threads, elements, repeat, trials, backends, c_pass)
                for side, rates in runs.items():
                    table[kernel, threads].setdefault(side, []).extend(rates)
        for kernel, threads in rows:
            rates = table[kernel, threads]
            slowest, median, fastest, c_p90 = c_summary(rates, pads)
            row = (f"{kernel:<10}{threads:>8}{slowest / 1e6:>10.1f}{median / 1e6:>10.1f}{fastest / 1e6:>8.1f}"
                   f"{c_p90 / 1e6:>8.1f}")
            flags = []
            for backend in backends:
                pooled_runs = pooled(rates, f"{backend}#")
                rate = float(statistics.median(pooled_runs))
                worst[backend] = min(worst[backend], rate / median)
                worst_best[backend] = min(worst_best[backend], rate / fastest)
                row += (f"{rate / 1e6:>9.1f}{rate / median:>8.2f}{rate / fastest:>6.2f}"
                        f"{float(np.quantile(pooled_runs, 0.9)) / c_p90:>6.2f}")
                flags.append("ok" if rate / median >= TARGET else "BELOW")
            if c_pass is not None:
                rate = float(statistics.median(rates["c-in-runner"]))
                row += f"{rate / 1e6:>12.1f}{rate / median:>8.2f}"
            print(f"{row}  {' '.join(flags)}", flush=True)
    for backend in backends:
        print(f"worst ratio ({backend}) {worst[backend]:.2f} of the C median (target >= {TARGET:.2f}); "
              f"{worst_best[backend]:.2f} of the fastest C placement's median")
    return 0


if __name__ == "__main__":
    sys.exit(main())
