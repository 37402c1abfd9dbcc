"""Benchmark: DRAM command statistics from a request stream (the Ramulator step), end to end.

Generates the Copy kernel's stream of the Ramulator reference (12,582,912 doubles per array:
4,718,592 requests), then times

1. ``simulate`` on the request arrays (mapping, scheduling, timing, refresh, statistics), and
2. the same from the Ramulator 1 trace file (reading and parsing included:
   ``trace_simulation.simulate_trace`` parses the memory-mapped file chunk by chunk in the
   preparing stage of the pipeline),

and prints requests/s, peak memory, the target (>= 20 M requests/s) and the ratio to Ramulator's
wall time for the same trace (``reference/ramulator/throughput.csv``). The chunks are prepared
in a forked worker process while the previous one is timed (``controller.PIPELINE_PROCESS``;
``--threads`` prepares them in a thread instead): its peak memory is printed separately (most of
its pages are shared with the benchmark's). ``--quick`` runs 1/8 of the stream. Usage:
``python3 benchmarks/bench_stats.py [--quick] [--json] [--threads]``.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

from hdeem_watch.dram import controller
from hdeem_watch.dram.controller import simulate
from hdeem_watch.dram.kernels import kernel_requests
from hdeem_watch.dram.memspec import load_memspec
from hdeem_watch.dram.request_traces import write_requests
from hdeem_watch.dram.trace_simulation import simulate_trace

REFERENCE = Path(__file__).resolve().parents[1] / "tests" / "data" / "ramulator"
TARGET_REQUESTS_PER_S = 20e6
ELEMENTS = 12_582_912


def _ramulator_copy() -> dict[str, float]:
    """Ramulator's requests/s on the Copy trace, per simulator (the fastest mode of each)."""
    best: dict[str, float] = {}
    with open(REFERENCE / "throughput.csv", newline="") as handle:
        for row in csv.DictReader(handle):
            if row["kernel"] == "copy":
                rate = float(row["requests"]) / float(row["wall_s"])
                best[row["sim"]] = max(best.get(row["sim"], 0.0), rate)
    return best


def _best_of(repeats: int, func):  # type: ignore[no-untyped-def]
    times = []
    result = None
    for _ in range(repeats):
        start = time.perf_counter()
        result = func()
        times.append(time.perf_counter() - start)
    return min(times), result


def main() -> int:
    """Run the benchmark; print the figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="1/8 of the stream, one repetition")
    parser.add_argument("--json", action="store_true", help="one JSON object per measurement")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", action="store_true", help="prepare chunks in a thread, not a worker process")
    args = parser.parse_args()
    controller.PIPELINE_PROCESS = not args.threads
    pipeline = "thread" if args.threads else "process"
    spec = load_memspec(REFERENCE / "ddr4_2133P_8Gb_x8_2r_8dev.json")
    elements = ELEMENTS // 8 if args.quick else ELEMENTS
    repeats = 1 if args.quick else args.repeats
    addresses, is_write = kernel_requests("copy", elements, threads=1)
    n = addresses.size
    baseline = _ramulator_copy()
    fastest_ramulator = max(baseline.values())
    rows = []
    seconds, result = _best_of(repeats, lambda: simulate(spec, addresses, is_write))
    rows.append(("arrays -> stats", seconds))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "copy.trace"
        write_requests(path, addresses, is_write)
        with open(path, "rb") as handle:  # written back now, not by the kernel during the timed runs
            os.fsync(handle.fileno())

        def from_file():  # type: ignore[no-untyped-def]
            return simulate_trace(spec, path, "ramulator")[0]

        file_seconds, _ = _best_of(repeats, from_file)
        rows.append(("trace file -> stats", file_seconds))
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    worker_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    for label, secs in rows:
        rate = n / secs
        record = {
            "bench": "stats", "what": label, "kernel": "copy", "requests": n, "seconds": round(secs, 4),
            "requests_per_s": rate, "target_requests_per_s": TARGET_REQUESTS_PER_S,
            "ratio_to_target": rate / TARGET_REQUESTS_PER_S,
            "ratio_to_ramulator_fastest": rate / fastest_ramulator,
            "ratio_to_ramulator": {sim: rate / r for sim, r in baseline.items()},
            "peak_rss_mb": round(peak_mb, 1), "worker_peak_rss_mb": round(worker_mb, 1), "pipeline": pipeline,
            "act": result.stats.total("act"), "cycles": result.cycles,
        }
        if args.json:
            sys.stdout.write(json.dumps(record) + "\n")
        else:
            print(f"{label:<22} {n:,} requests in {secs:.3f} s = {rate / 1e6:6.2f} M requests/s "
                  f"(target {TARGET_REQUESTS_PER_S / 1e6:.0f} M/s: {rate / TARGET_REQUESTS_PER_S:.2f}x; "
                  f"Ramulator fastest {fastest_ramulator / 1e6:.2f} M/s: {rate / fastest_ramulator:.1f}x; "
                  + ", ".join(f"{sim} {rate / r:.0f}x" for sim, r in baseline.items()) + ")")
    if not args.json:
        print(f"peak RSS {peak_mb:.0f} MB; {pipeline} pipeline"
              + (f", worker process peak RSS {worker_mb:.0f} MB (mostly pages shared with this one)"
               if not args.threads else "")
              + " (Ramulator 2: 147 MB, Ramulator 1: 5.5 MB streaming)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
