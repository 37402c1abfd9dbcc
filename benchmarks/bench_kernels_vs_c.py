"""Bench kernels vs the same stride-8 loops in C (gcc -O2, pthreads, same pinned CPUs).

Target (DESIGN.md §8): each hdeem-watch kernel reaches >= 90 % of the line rate of the C loop with
the same thread count. The C program is written and built by this script; both sides use the same
arrays size, repeat count, CPU pinning, first touch by the worker and timing method (all workers
ready, window opens, ``repeat`` passes, all workers done). Trials of C and hdeem-watch alternate
(C, hw, hw, C, ...) so a change of machine load hits both alike; each figure is the best of
``--trials``.

Usage::

    python3 benchmarks/bench_kernels_vs_c.py            # 2**25 doubles/array, repeat 2, 7 trials
    python3 benchmarks/bench_kernels_vs_c.py --quick    # 2**24, repeat 2, 3 trials
    python3 benchmarks/bench_kernels_vs_c.py --backend both   # threads and processes side by side

Short windows and many alternating trials, best kept, because a shared machine preempts long
windows: the best of several short windows is the closest to an undisturbed run on both sides.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from hdeem_watch.bench.runner import choose_cpus, run_one
from hdeem_watch.bench.schedule import KERNELS, RunSpec
from hdeem_watch.bench.system import llc_total_bytes

TARGET = 0.90

C_SOURCE = r"""
#define _GNU_SOURCE
#include <pthread.h>
#include <sched.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static double *a, *b, *c;
static long lines, repeat;
static int threads, kernel;
static int cpus[1024];
static double sums[1024];
static pthread_barrier_t ready, go;

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
    for (long r = 0; r < repeat; r++) {
        sum = 0.0;
        switch (kernel) {
        case 0: for (long k = lo * 8; k < hi * 8; k += 8) sum += a[k]; break;
        case 1: for (long k = lo * 8; k < hi * 8; k += 8) a[k] = 2.0; break;
        case 2: for (long k = lo * 8; k < hi * 8; k += 8) b[k] = 2.0 * a[k]; break;
        case 3: for (long k = lo * 8; k < hi * 8; k += 8) c[k] = a[k] + b[k]; break;
        case 4: for (long k = lo * 8; k < hi * 8; k += 8) a[k] = b[k] + 2.0 * a[k]; break;
        case 5: for (long k = lo * 8; k < hi * 8; k += 8) b[k] = a[k]; break;
        case 6: for (long k = lo * 8; k < hi * 8; k += 8) a[k] = 2.0 * a[k]; break;
        }
    }
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
        a = malloc(elements * 8); b = narrays > 1 ? malloc(elements * 8) : NULL;
        c = narrays > 2 ? malloc(elements * 8) : NULL;
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


def build(workdir: Path) -> Path:
    """Write and compile the C loops with gcc -O2 -pthread; return the executable."""
    source = workdir / "stride8.c"
    source.write_text(C_SOURCE)
    exe = workdir / "stride8"
    subprocess.run(["gcc", "-O2", "-pthread", "-o", str(exe), str(source)], check=True)
    return exe


def c_seconds(exe: Path, kernel: str, elements: int, repeat: int, trials: int, cpus: list[int]) -> float:
    """Best wall time of ``repeat`` passes of the C loop."""
    out = subprocess.run([str(exe), kernel, str(elements), str(repeat), str(trials),
                          ",".join(map(str, cpus))], capture_output=True, text=True, check=True).stdout
    return float(out.split()[0])


def py_seconds(kernel: str, threads: int, elements: int, repeat: int, backend: str) -> float:
    """Wall time of ``repeat`` passes of the hdeem-watch kernel."""
    return run_one(RunSpec(kernel, threads, elements, repeat), backend=backend).seconds


def best_times(exe: Path, kernel: str, threads: int, elements: int, repeat: int, trials: int,
               backends: list[str]) -> dict[str, float]:
    """Best times of C and each backend over trials in rotating order (C first, then shifted)."""
    cpus = choose_cpus(threads)
    sides = ["c", *backends]
    best = dict.fromkeys(sides, float("inf"))
    for trial in range(trials):
        shift = trial % len(sides)
        for side in sides[shift:] + sides[:shift]:
            if side == "c":
                seconds = c_seconds(exe, kernel, elements, repeat, 1, cpus)
            else:
                seconds = py_seconds(kernel, threads, elements, repeat, side)
            best[side] = min(best[side], seconds)
    return best


def main(argv: list[str] | None = None) -> int:
    """Run the comparison and print one row per kernel and thread count."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller arrays, fewer passes and trials")
    parser.add_argument("--elements", type=int, help="doubles per array (default 2**25, quick 2**24)")
    parser.add_argument("--repeat", type=int, help="passes per run (default 2)")
    parser.add_argument("--trials", type=int, help="runs per figure, best kept (default 7, quick 3)")
    parser.add_argument("--threads", default=None, help="comma-separated thread counts (default 1 and all CPUs)")
    parser.add_argument("--kernels", default=",".join(KERNELS))
    parser.add_argument("--backend", default="thread", choices=("thread", "process", "both"),
                        help="hdeem-watch worker backend; 'both' measures threads and processes side by side")
    args = parser.parse_args(argv)
    elements = args.elements or (1 << 24 if args.quick else 1 << 25)
    repeat = args.repeat or 2
    trials = args.trials or (3 if args.quick else 7)
    backends = ["thread", "process"] if args.backend == "both" else [args.backend]
    ncpu = len(os.sched_getaffinity(0))
    counts = [int(t) for t in args.threads.split(",")] if args.threads else sorted({1, ncpu})
    llc = llc_total_bytes(sorted(os.sched_getaffinity(0)))
    print(f"arrays: {elements} doubles = {elements * 8 / 2**20:.0f} MiB each; LLC "
          f"{(llc or 0) / 2**20:.0f} MiB; repeat {repeat}; best of {trials}; "
          f"load average {os.getloadavg()[0]:.2f}")
    header = f"{'kernel':<10}{'threads':>8}{'C Mlines/s':>12}"
    for backend in backends:
        header += f"{backend + ' Mlines/s':>18}{'ratio':>7}"
    print(f"{header}  target >= {TARGET:.0%} of C")
    lines = (elements + 7) // 8
    worst = dict.fromkeys(backends, float("inf"))
    with tempfile.TemporaryDirectory(prefix="bench-c-") as tmp:
        exe = build(Path(tmp))
        for kernel in args.kernels.split(","):
            for threads in counts:
                best = best_times(exe, kernel, threads, elements, repeat, trials, backends)
                c_rate = lines * repeat / best["c"]
                row = f"{kernel:<10}{threads:>8}{c_rate / 1e6:>12.1f}"
                flags = []
                for backend in backends:
                    rate = lines * repeat / best[backend]
                    ratio = rate / c_rate
                    worst[backend] = min(worst[backend], ratio)
                    row += f"{rate / 1e6:>18.1f}{ratio:>7.2f}"
                    flags.append("ok" if ratio >= TARGET else "BELOW")
                print(f"{row}  {' '.join(flags)}", flush=True)
    for backend in backends:
        print(f"worst ratio ({backend}) {worst[backend]:.2f} (target >= {TARGET:.2f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
