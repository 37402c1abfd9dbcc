"""Benchmark of ``hdeem-watch report``: wall time of the whole command on the state of a real demo.

Phases:

1. **state**: ``hdeem-watch demo --headless --duration S`` (default 120 s, ``--quick`` 30 s) into a
   temporary state directory — or an existing ``--state-dir``.
2. **report**: ``hdeem-watch report --state-dir DIR --format F`` as a fresh process (imports
   included), ``--repeat`` times per format (png, svg, html); reported: the median and the worst wall
   time per format against the target (≤ 10 s: "in seconds"), and, in-process, how long reading the
   state takes.

Usage: ``python3 benchmarks/bench_report.py [--quick] [--seconds S] [--state-dir DIR] [--repeat N] [--json]``.
Needs the ``report`` extra (matplotlib).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET_S = 10.0


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT / "src") + os.pathsep + os.environ.get("PYTHONPATH", "")}


def _demo_state(seconds: float, state_dir: Path) -> None:
    subprocess.run([sys.executable, "-m", "hdeem_watch", "demo", "--headless", "--duration", str(seconds),
                    "--state-dir", str(state_dir)], env=_env(), check=True, stdout=subprocess.DEVNULL)


def _time_report(state_dir: Path, out: Path, fmt: str) -> float:
    started = time.perf_counter()
    subprocess.run([sys.executable, "-m", "hdeem_watch", "report", "--state-dir", str(state_dir), "--out", str(out),
                    "--format", fmt], env=_env(), check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - started


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a 30 s demo and 2 repeats")
    parser.add_argument("--seconds", type=float, default=None, help="demo length (default 120)")
    parser.add_argument("--state-dir", type=Path, default=None, help="use this state instead of a new demo")
    parser.add_argument("--repeat", type=int, default=None, help="reports per format (default 5)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args()
    seconds = args.seconds or (30.0 if args.quick else 120.0)
    repeat = args.repeat or (2 if args.quick else 5)
    sys.path.insert(0, str(ROOT / "src"))
    from hdeem_watch.report.state_reader import read_state

    with tempfile.TemporaryDirectory(prefix="bench-report-") as tmp:
        state = args.state_dir
        if state is None:
            state = Path(tmp) / "state"
            _demo_state(seconds, state)
        started = time.perf_counter()
        data = read_state(state)
        read_s = time.perf_counter() - started
        results = {}
        for fmt in ("png", "svg", "html"):
            times = [_time_report(state, Path(tmp) / f"out-{fmt}", fmt) for _ in range(repeat)]
            results[fmt] = {"median_s": statistics.median(times), "max_s": max(times)}
    summary = {"runs": len(data.runs), "fits": len(data.fit_history), "read_state_s": read_s, "target_s": TARGET_S,
               "formats": results}
    if args.json:
        print(json.dumps(summary))
        return 0
    print(f"state: {summary['runs']} runs, {summary['fits']} fits; reading it: {read_s * 1e3:.0f} ms")
    for fmt, r in results.items():
        print(f"report --format {fmt:<4}  median {r['median_s']:.2f} s  worst {r['max_s']:.2f} s  "
              f"target <= {TARGET_S:g} s  ratio {TARGET_S / r['max_s']:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
