"""Benchmark of the simulated node's poll as the daemon calls it: once every 40 ms, caches cold.

The watched daemon polls its source 25 times a second; on this kind of VM the code after each
40-ms sleep runs several times slower than in a tight loop, so the figure is measured the same
way: ``SimSource.poll()`` after a 40 ms sleep, its thread CPU time, for ``--seconds`` of polls on
the idle node (the daemon's steady state). Reported: µs of CPU per poll with the default idle
block length (``block_s``, samples generated ahead) and with the 1-s blocks it replaced (the
baseline), repeats alternating, medians, and the ratio.

Usage: ``python3 benchmarks/bench_sim_poll.py [--seconds S] [--repeats N]``.
"""

from __future__ import annotations

import argparse
import inspect
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from hdeem_watch.sources.sim import SimSource

#: The sim's idle block length (its default) and the one it replaced (the baseline).
DEFAULT_BLOCK_S = float(inspect.signature(SimSource).parameters["block_s"].default)
BASELINE_BLOCK_S = 1.0
#: The daemon's poll period (s).
POLL_S = 0.04


def cpu_per_poll_us(block_s: float, seconds: float) -> float:
    """Mean thread CPU (µs) of one ``poll()`` of an idle sim polled every 40 ms for ``seconds``."""
    sim = SimSource(seed=1, block_s=block_s)
    sim.open()
    total, polls = 0, 0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        time.sleep(POLL_S)
        start = time.thread_time_ns()
        sim.poll()
        total += time.thread_time_ns() - start
        polls += 1
    sim.close()
    return total / polls / 1000


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="polling time per measurement")
    parser.add_argument("--repeats", type=int, default=3, help="measurements per setting (alternating)")
    args = parser.parse_args(argv)
    default, baseline = [], []
    for _ in range(args.repeats):
        default.append(cpu_per_poll_us(DEFAULT_BLOCK_S, args.seconds))
        baseline.append(cpu_per_poll_us(BASELINE_BLOCK_S, args.seconds))
    d, b = statistics.median(default), statistics.median(baseline)
    print(f"sim poll every {POLL_S * 1e3:.0f} ms, idle node, {args.repeats} × {args.seconds:.0f} s alternating")
    print(f"  default blocks ({DEFAULT_BLOCK_S:g} s): {d:7.1f} µs CPU per poll  ({' / '.join(f'{x:.1f}' for x in default)})")
    print(f"  baseline blocks ({BASELINE_BLOCK_S:g} s): {b:7.1f} µs CPU per poll  ({' / '.join(f'{x:.1f}' for x in baseline)})")
    print(f"  ratio default/baseline: {d / b:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
