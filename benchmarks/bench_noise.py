"""Benchmark of the daemon's OS noise on a compute node: wake-ups, CPU and a fixed-work-quantum loop.

HPC centres judge a node daemon by the noise it adds to bulk-synchronous applications. Two parts:

1. **Wake-ups and CPU** (load-independent): the daemon as a real process with the simulated node at
   speed 1 (HDEEM's full rate), first with nobody watching, then with 4 subscriber processes. Over
   ``--seconds`` each: its threads, its context switches per second (voluntary + involuntary, summed
   over ``/proc/<pid>/task/*/status`` — every wake-up of every thread is one voluntary switch) and
   its CPU share of one core. Targets: unwatched ≤ 2 switches/s and ≤ 0.1 %; watched ≤ 2 % with 0
   lost samples. Also: how long a subscriber that connects to the quiet daemon waits for its first
   live sample (target: one poll period after the daemon sees the subscription).
2. **FWQ** (fixed work quantum, as in OS-noise studies): a C loop pinned to one core times
   ``--quanta`` equal quanta of pure arithmetic; slowdown of a quantum = its time / the fastest
   quantum of the same run − 1. The daemon's threads are pinned to the same core (the worst case:
   each of its wake-ups lands on the measured core); the subscribers to the others. Conditions,
   interleaved ``--repeats`` times: no daemon (the daemon SIGSTOPped), unwatched, watched. Reported
   per condition: the median over repeats of each run's median, p99 and max slowdown; the noise
   floor is the spread (max − min) of the no-daemon runs' p99 — a difference below it is not
   measurable on this machine. On a shared machine ``--nice -19`` (root) keeps other busy processes
   from preempting the FWQ as often; the daemon's threads then weigh less too (the scheduler may
   delay a wake-up instead of interrupting a quantum), so niced figures are a lower bound.

Usage: ``python3 benchmarks/bench_noise.py [--quick] [--seconds S] [--repeats N] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import psutil
import zmq

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "src"))

import bench_daemon  # noqa: E402
from hdeem_watch.wire import protocol  # noqa: E402

FWQ_C = r"""
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

static inline int64_t now_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

int main(int argc, char **argv) {
    long quanta = atol(argv[1]), work = atol(argv[2]);
    int64_t *t = malloc(sizeof(int64_t) * quanta);
    volatile double x = 1.0;
    for (long q = 0; q < quanta; q++) {
        int64_t t0 = now_ns();
        for (long i = 0; i < work; i++) x = x * 1.0000001 + 1e-9;
        t[q] = now_ns() - t0;
    }
    fwrite(t, sizeof(int64_t), quanta, stdout);
    return 0;
}
"""


def build_fwq(directory: Path) -> Path:
    """Compile the FWQ loop (``cc -O2``)."""
    source, binary = directory / "fwq.c", directory / "fwq"
    source.write_text(FWQ_C)
    subprocess.run(["cc", "-O2", "-o", str(binary), str(source)], check=True)
    return binary


def run_fwq(binary: Path, core: int, quanta: int, work: int, nice: int = 0) -> np.ndarray:
    """One FWQ run pinned to ``core`` at niceness ``nice``: the quanta's durations (ns)."""
    out = subprocess.run(["nice", "-n", str(nice), "taskset", "-c", str(core), str(binary), str(quanta), str(work)],
                         check=True, stdout=subprocess.PIPE).stdout
    return np.frombuffer(out, dtype=np.int64)


def calibrate_work(binary: Path, core: int, quantum_ms: float) -> int:
    """Iterations of the work loop that take about ``quantum_ms`` (the fastest of a short run)."""
    probe = 100_000
    fastest = float(np.min(run_fwq(binary, core, 200, probe)))
    return max(1, round(probe * quantum_ms * 1e6 / fastest))


def slowdowns(durations: np.ndarray) -> dict[str, float]:
    """Median, p99 and max slowdown (%) of a run's quanta against its fastest quantum."""
    rel = durations / float(np.min(durations)) - 1.0
    return {"median": float(np.median(rel) * 100), "p99": float(np.percentile(rel, 99) * 100),
            "max": float(np.max(rel) * 100)}


# -- the daemon's own wake-ups and CPU ---------------------------------------------------------------


def switches(pid: int) -> tuple[int, int]:
    """(threads, voluntary + involuntary context switches summed over the process's threads)."""
    total = threads = 0
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            text = (task / "status").read_text()
        except OSError:  # the thread ended
            continue
        threads += 1
        total += sum(int(line.split()[1]) for line in text.splitlines() if "ctxt_switches" in line)
    return threads, total


def measure(pid: int, seconds: float) -> dict[str, float]:
    """Threads, context switches per second and CPU % of one core over ``seconds``."""
    proc = psutil.Process(pid)
    _, s0 = switches(pid)
    c0, t0 = bench_daemon.cpu_seconds(proc), time.monotonic()
    time.sleep(seconds)
    threads, s1 = switches(pid)
    c1, t1 = bench_daemon.cpu_seconds(proc), time.monotonic()
    return {"threads": threads, "switches_per_s": (s1 - s0) / (t1 - t0), "cpu_percent": 100 * (c1 - c0) / (t1 - t0)}


def first_live_sample(pub: str, timeout_s: float = 10.0) -> tuple[float, float]:
    """Seconds from connecting to the first samples message, and to the first sample younger than 0.1 s."""
    sock = zmq.Context.instance().socket(zmq.SUB)
    sock.setsockopt(zmq.LINGER, 0)
    t0 = time.monotonic()
    sock.connect(pub)
    sock.setsockopt(zmq.SUBSCRIBE, b"hw1/")
    first = live = float("nan")
    try:
        while time.monotonic() - t0 < timeout_s and live != live:
            if not sock.poll(100):
                continue
            msg = protocol.decode(sock.recv_multipart())
            if msg.kind != "samples":
                continue
            t, _ = msg.samples()
            if first != first:
                first = time.monotonic() - t0
            if t.size and (time.time_ns() - int(t[-1])) < 100_000_000:
                live = time.monotonic() - t0
    finally:
        sock.close(0)
    return first, live


def pin(pid: int, cores: set[int]) -> None:
    """Pin every thread of ``pid`` (threads it starts later inherit it)."""
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            os.sched_setaffinity(int(task.name), cores)
        except OSError:
            continue


# -- the phases --------------------------------------------------------------------------------------


def wakeups(pid: int, pub: str, seconds: float, subscribers: int) -> dict[str, Any]:
    """Part 1: unwatched, then the first live sample of a new subscriber, then watched."""
    unwatched = measure(pid, seconds)
    first, live = first_live_sample(pub)
    time.sleep(1.0)  # its unsubscription seen: quiet again
    procs, _ready, results = bench_daemon.run_subscribers(pub, subscribers, seconds + 4)
    time.sleep(bench_daemon.WARMUP_S)
    watched = measure(pid, seconds)
    subs = [results.get(timeout=60) for _ in procs]
    for p in procs:
        p.join(timeout=30)
    watched |= {"lost_samples": sum(s["missing_samples"] + s["missed_messages"] for s in subs),
                "p99_latency_ms": max(s["p99_ms"] for s in subs),
                "rate_per_subscriber": float(np.mean([s["samples"] / s["seconds"] for s in subs]))}
    return {"unwatched": unwatched, "watched": watched, "first_samples_s": first, "first_live_sample_s": live}


def fwq(pid: int, pub: str, *, core: int, repeats: int, quanta: int, quantum_ms: float,
        subscribers: int, directory: Path, nice: int = 0) -> dict[str, Any]:
    """Part 2: FWQ runs without the daemon (SIGSTOPped), unwatched and watched, interleaved."""
    binary = build_fwq(directory)
    work = calibrate_work(binary, core, quantum_ms)
    others = set(range(os.cpu_count() or 1)) - {core} or {core}
    pin(pid, {core})
    runs: dict[str, list[dict[str, float]]] = {"none": [], "unwatched": [], "watched": []}
    for _ in range(repeats):
        os.kill(pid, signal.SIGSTOP)
        try:
            runs["none"].append(slowdowns(run_fwq(binary, core, quanta, work, nice)))
        finally:
            os.kill(pid, signal.SIGCONT)
        time.sleep(3.0)
        runs["unwatched"].append(slowdowns(run_fwq(binary, core, quanta, work, nice)))
        seconds = quanta * quantum_ms / 1e3 * 1.5 + 10
        procs, _ready, _results = bench_daemon.run_subscribers(pub, subscribers, seconds)
        for p in procs:
            pin(p.pid, others)
        time.sleep(3.0)
        runs["watched"].append(slowdowns(run_fwq(binary, core, quanta, work, nice)))
        for p in procs:
            p.terminate()
            p.join(timeout=30)
        time.sleep(2.0)
    summary = {name: {key: float(np.median([r[key] for r in rs])) for key in ("median", "p99", "max")}
               for name, rs in runs.items()}
    floor = [r["p99"] for r in runs["none"]]
    return {"core": core, "nice": nice, "quantum_ms": quantum_ms, "quanta": quanta, "repeats": repeats, "work": work,
            "runs": runs, "median_of_repeats": summary, "noise_floor_p99": float(max(floor) - min(floor))}


def report(result: dict[str, Any]) -> None:
    w = result["wakeups"]
    for name in ("unwatched", "watched"):
        m = w[name]
        extra = (f", lost {m['lost_samples']}, {m['rate_per_subscriber']:.0f} Sa/s per subscriber, "
                 f"p99 latency {m['p99_latency_ms']:.0f} ms") if name == "watched" else ""
        print(f"{name:>10}: {m['threads']} threads, {m['switches_per_s']:.2f} context switches/s, "
              f"CPU {m['cpu_percent']:.3f} % of a core{extra}")
    print(f"new subscriber of the quiet daemon: first samples after {w['first_samples_s'] * 1e3:.0f} ms, "
          f"first live sample after {w['first_live_sample_s'] * 1e3:.0f} ms")
    f = result.get("fwq")
    if f:
        print(f"FWQ on core {f['core']} (nice {f['nice']}): {f['quanta']} quanta of {f['quantum_ms']} ms, "
              f"{f['repeats']} repeats "
              f"(median over repeats; slowdown % vs the run's fastest quantum)")
        for name, s in f["median_of_repeats"].items():
            print(f"  {name:>10}: median {s['median']:.2f}  p99 {s['p99']:.2f}  max {s['max']:.1f}")
        print(f"  noise floor (spread of the no-daemon p99 over repeats): {f['noise_floor_p99']:.2f} %")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="each wake-up/CPU window (s)")
    parser.add_argument("--repeats", type=int, default=5, help="FWQ repeats per condition")
    parser.add_argument("--quanta", type=int, default=20_000, help="FWQ quanta per run")
    parser.add_argument("--quantum-ms", type=float, default=0.5, help="FWQ quantum (ms)")
    parser.add_argument("--core", type=int, default=(os.cpu_count() or 1) - 1, help="the FWQ (and daemon) core")
    parser.add_argument("--subscribers", type=int, default=4)
    parser.add_argument("--nice", type=int, default=0,
                        help="FWQ niceness (-19 as root: other busy processes on a shared machine preempt it less)")
    parser.add_argument("--no-fwq", action="store_true", help="only the wake-ups and CPU")
    parser.add_argument("--quick", action="store_true", help="10 s windows, 2 repeats of 4000 quanta")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    if args.quick:
        args.seconds, args.repeats, args.quanta = 10.0, 2, 4000
    result: dict[str, Any] = {"load_average": os.getloadavg()}
    with tempfile.TemporaryDirectory(prefix="hwn-") as tmp:
        proc, pub, _control = bench_daemon.start_daemon(Path(tmp), 1.0)
        try:
            time.sleep(5.0)  # past the start: the model built, the first quiet period begun
            result["wakeups"] = wakeups(proc.pid, pub, args.seconds, args.subscribers)
            if not args.no_fwq:
                result["fwq"] = fwq(proc.pid, pub, core=args.core, repeats=args.repeats, quanta=args.quanta,
                                    quantum_ms=args.quantum_ms, subscribers=args.subscribers, directory=Path(tmp),
                                    nice=args.nice)
        finally:
            proc.terminate()
            proc.wait(timeout=30)
    result["load_average_after"] = os.getloadavg()
    if args.json:
        print(json.dumps(result, indent=1))
    else:
        report(result)
        print(f"load average before/after: {result['load_average'][0]:.1f} / {result['load_average_after'][0]:.1f}")


if __name__ == "__main__":
    main()
