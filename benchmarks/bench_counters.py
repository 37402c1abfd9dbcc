"""Memory-controller counters (issue #17 targets): polling overhead, and DRAM energy from counters.

1. **Overhead** of counter polling at the default poll rate (40 ms polls, counters read at each 1 s
   heartbeat and at window edges, ``CounterWindows.due`` asked at every poll): CPU seconds per
   second of daemon time, in % of one core (target ≤ 0.5 %). Measured for the sim's counters
   (idle node, and an opaque job in progress: its phases are summed at every read) and for the perf
   path on the Haswell-EP fixture plan (8 channels × 14 events = 112 ``read(2)`` calls of real
   software events through the real ``PerfCounterReader``, then the per-role arithmetic).
2. **Accuracy** on the simulated node with its sensor effects (noise, 0.125 W steps, gains, offsets):
   calibrate on kernel runs (two passes of a 14-run schedule, counters on), then ≥ 20 opaque jobs
   (hidden stream/random/idle mixes, 4-12 s); per job ``|predicted / measured − 1|`` of the DRAM energy
   with the fit from before the job (target: median ≤ 5 %). And the kernel runs' counted ACT/RD/WR
   against the kernel model's (target: within 10 %).

3. **The daemon itself**: ``hdeem-watch daemon --source sim`` at speed 1 with one subscriber taking
   every sample (so it polls every 40 ms), with and without ``--counters sim``, alternating, for
   ``--daemon-seconds`` each after a 3 s warm-up: the process's CPU share of one core (psutil). The
   difference includes the noise of a shared machine; the in-process figures of 1. are the precise ones.

Each figure is the median over ``--repeats`` timing runs (overhead) or ``--seeds`` sim seeds (accuracy).

Usage: ``PYTHONPATH=src python3 benchmarks/bench_counters.py [--seeds 3] [--jobs 20] [--repeats 5]
[--daemon-seconds 20] [--daemon-repeats 3]`` (``--daemon-seconds 0`` skips 3.)
"""

from __future__ import annotations

import argparse
import random
import runpy
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from counter_rig import CounterSimNode  # benchmarks/counter_rig.py, beside this script
from hdeem_watch.counters.host_plan import plan_host
from hdeem_watch.counters.perf_counters import PerfCounters
from hdeem_watch.counters.perf_reader import PerfCounterReader
from hdeem_watch.counters.permissions import check_access
from hdeem_watch.daemon.counters.windows import CounterWindows
from hdeem_watch.perf_event import PERF_COUNT_SW_TASK_CLOCK, PERF_TYPE_SOFTWARE
from hdeem_watch.sim.counters import SimCounters
from hdeem_watch.sources.base import RunEvent
from hdeem_watch.sources.sim import SimSource

FIXTURES = Path(__file__).resolve().parents[1] / "tests" / "counters" / "fixtures"
POLL_S, HEARTBEAT_S = 0.04, 1.0
CURRENTS = ("idd0", "idd2n", "idd3n", "idd4r", "idd4w", "idd2p", "idd3p")
SCHEDULE = [("idle", 1, 0, 1), ("read", 12, 1 << 23, 480), ("triad", 4, 1 << 23, 320), ("idle", 1, 0, 1),
            ("copy", 8, 1 << 23, 400), ("read", 2, 1 << 22, 320), ("add", 12, 1 << 23, 320),
            ("assign", 6, 1 << 23, 400), ("idle", 1, 0, 1), ("triad", 12, 1 << 23, 480),
            ("read", 6, 1 << 23, 320), ("copy", 2, 1 << 22, 320), ("triad", 24, 1 << 23, 480),
            ("read", 24, 1 << 23, 480)]


def cpu_per_call(call: Any, n: int) -> float:
    """CPU seconds per call (process time over ``n`` calls)."""
    call()
    t0 = time.process_time()
    for _ in range(n):
        call()
    return (time.process_time() - t0) / n


def overhead_percent(read_s: float, due_s: float) -> float:
    """% of one core: one read per heartbeat + one ``due`` per poll."""
    return 100.0 * (read_s / HEARTBEAT_S + due_s / POLL_S)


def sim_overhead(job: bool) -> float:
    now = [0]
    sim = SimSource(seed=1, clock=lambda: now[0], wall_clock=lambda: 0, background_plans=False)
    sim.open()
    if job:
        sim.on_run(RunEvent("start", "r1", "job", 24, 0, 1, 0))
    counters = SimCounters(sim)
    windows = CounterWindows("sim", table_key="haswell-ep", ranks=2, refresh_complete=False, sensors={},
                             heartbeat_ns=10**9)
    seconds = [0]

    def read() -> None:
        seconds[0] += 1
        now[0] = seconds[0] * 10**9
        windows.observe(counters.read(), now_mono_ns=now[0])

    read_s = cpu_per_call(read, 200)
    due_s = cpu_per_call(lambda: windows.due(now[0], ()), 20000)
    return overhead_percent(read_s, due_s)


def perf_overhead() -> float:
    """The Haswell-EP plan's 112 events, each a real software event of this process."""
    cpuinfo = (FIXTURES / "cpuinfo" / "haswell_ep").read_text()
    with tempfile.TemporaryDirectory() as trees:  # the PMU tree as the tests build it
        runpy.run_path(str(FIXTURES.parent / "pmu_trees.py"))["build"](Path(trees))
        plan = plan_host(Path(trees) / "sysfs_haswell_ep", cpuinfo_text=cpuinfo,
                         access=check_access(paranoid=0, capabilities=0), ranks=2)
    real = PerfCounterReader(pid=0, exclude_kernel=True)

    class SoftwareStandIn:  # the uncore events' opens redirected to a software event; reads are real
        def open(self, pmu_type: int, config: int, cpu: int, config1: int = 0, config2: int = 0) -> int:
            return real.open(PERF_TYPE_SOFTWARE, PERF_COUNT_SW_TASK_CLOCK, cpu=-1)

        read, close = real.read, real.close

    counters = PerfCounters(plan, SoftwareStandIn(), sample_time=lambda t: t, clock=time.monotonic_ns,
                            ranks=2)
    windows = CounterWindows("perf", table_key="haswell-ep", ranks=2, refresh_complete=False, sensors={})
    read_s = cpu_per_call(lambda: windows.observe(counters.read(), now_mono_ns=time.monotonic_ns()), 200)
    due_s = cpu_per_call(lambda: windows.due(time.monotonic_ns(), ()), 20000)
    counters.close()
    return overhead_percent(read_s, due_s)


def daemon_cpu_percent(counters: bool, seconds: float) -> float:
    """CPU % of one core of a real sim daemon (speed 1) with one draining subscriber."""
    import os
    import subprocess
    import sys
    import threading

    import psutil
    import zmq

    from hdeem_watch.wire.client import ControlClient, DaemonUnreachable

    with tempfile.TemporaryDirectory() as directory:
        pub, control = f"ipc://{directory}/p.sock", f"ipc://{directory}/c.sock"
        command = [sys.executable, "-m", "hdeem_watch", "daemon", "--source", "sim", "--pub", pub, "--control",
                   control, "--state-dir", f"{directory}/state", "--node", "bench"]
        if counters:
            command += ["--counters", "sim"]
        env = {k: v for k, v in os.environ.items() if not k.startswith("HDEEM_WATCH_")}
        proc = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        stop = threading.Event()
        try:
            with ControlClient(control, timeout_s=1.0) as client:
                for _ in range(300):
                    try:
                        client.call("ping")
                        break
                    except DaemonUnreachable:
                        time.sleep(0.1)
            sub = zmq.Context.instance().socket(zmq.SUB)
            sub.connect(pub)
            sub.setsockopt(zmq.SUBSCRIBE, b"hw1/")

            def drain() -> None:
                while not stop.is_set():
                    if sub.poll(100):
                        sub.recv_multipart()

            thread = threading.Thread(target=drain, daemon=True)
            thread.start()
            time.sleep(3.0)
            process = psutil.Process(proc.pid)
            before, t0 = process.cpu_times(), time.monotonic()
            time.sleep(seconds)
            after, t1 = process.cpu_times(), time.monotonic()
            stop.set()
            thread.join()
            sub.close(linger=0)
        finally:
            proc.terminate()
            proc.wait(timeout=30)
    used = (after.user - before.user) + (after.system - before.system)
    return 100.0 * used / (t1 - t0)


def accuracy(seed: int, jobs: int) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as directory:
        node = CounterSimNode(Path(directory), seed=seed, realistic=True, currents=CURRENTS)
        try:
            node.advance(1.0)
            kernel_runs = [node.run(*spec) for spec in SCHEDULE * 2]
            rng = random.Random(seed)
            job_runs = [node.run(None, rng.choice((4, 8, 12, 24)), seconds=rng.uniform(4.0, 12.0))
                        for _ in range(jobs)]
        finally:
            node.close()
    errors = [abs(r["model"]["predicted_j"] / r["dram_energy_j"] - 1) for r in job_runs]
    ratios: dict[str, list[float]] = {"act": [], "rd": [], "wr": []}
    for run in kernel_runs:
        for name, value in run["model"]["kernel_model"]["ratio"].items():
            if value is not None:
                ratios[name].append(abs(value - 1))
    return {"job_error_median": statistics.median(errors), "job_error_max": max(errors),
            **{f"{k}_dev_median": statistics.median(v) for k, v in ratios.items()},
            **{f"{k}_dev_max": max(v) for k, v in ratios.items()}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--jobs", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--daemon-seconds", type=float, default=20.0)
    parser.add_argument("--daemon-repeats", type=int, default=3)
    args = parser.parse_args()
    print("counter polling overhead, % of one core (40 ms polls, 1 s reads; median of "
          f"{args.repeats}; target <= 0.5 %)")
    for name, measure in (("sim, idle node", lambda: sim_overhead(False)), ("sim, opaque job running",
                                                                            lambda: sim_overhead(True)),
                          ("perf, Haswell-EP plan (112 events)", perf_overhead)):
        values = [measure() for _ in range(args.repeats)]
        print(f"  {name:40s} {statistics.median(values):7.3f} %  (runs: {', '.join(f'{v:.3f}' for v in values)})")
    if args.daemon_seconds > 0:
        off, on = [], []
        for _ in range(args.daemon_repeats):
            off.append(daemon_cpu_percent(False, args.daemon_seconds))
            on.append(daemon_cpu_percent(True, args.daemon_seconds))
        print(f"  {'daemon process, counters off':40s} {statistics.median(off):7.3f} %  (runs: "
              f"{', '.join(f'{v:.3f}' for v in off)})")
        print(f"  {'daemon process, --counters sim':40s} {statistics.median(on):7.3f} %  (runs: "
              f"{', '.join(f'{v:.3f}' for v in on)})")
        print(f"  {'difference of the medians':40s} {statistics.median(on) - statistics.median(off):7.3f} %")
    print(f"\naccuracy on the simulated node ({len(SCHEDULE) * 2} kernel runs to calibrate, {args.jobs} opaque jobs; "
          f"median over {args.seeds} seeds)")
    results = [accuracy(seed, args.jobs) for seed in range(1, args.seeds + 1)]
    for key in results[0]:
        values = [r[key] for r in results]
        print(f"  {key:22s} {100 * statistics.median(values):7.2f} %  (seeds: "
              f"{', '.join(f'{100 * v:.2f}' for v in values)})")


if __name__ == "__main__":
    main()
