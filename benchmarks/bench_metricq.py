"""Benchmark of the MetricQ source: CPU share at one node's full rate; nodes through one broker.

A private RabbitMQ node, the manager stand-in and a recording metricq Sink of the tests
(tests/metricq/standin.py) make the MetricQ side. Nodes are simulated by a synthetic publisher
process that sends the daemon's wire protocol (``protocol.encode_samples``) at HDEEM's full rate
per node — BLADE 1000 Sa/s and six channels at 100 Sa/s, one batch per channel every 40 ms, i.e.
1 600 samples/s — so that the source processes and the broker are what is measured, not 64 daemons.

Phases:

1. **cpu**: one node through one ``hdeem-watch metricq-source`` process for ``--seconds``: the
   source's CPU share of one core (target ≤ 5 %).
2. **nodes**: ``N`` nodes (1, 4, 8, 16, 32, 64; ``--quick``: 1, 4, 8) through one broker, the nodes
   spread over ``--sources`` source processes, for ``--seconds`` each: data points published by the
   nodes vs received by the sink (7 power metrics and 4 above-baseline metrics per node; target 0
   lost), stopping at the first N that loses any. Reported: the largest N without loss (target 64).

Usage: ``python3 benchmarks/bench_metricq.py [--quick] [--seconds S] [--sources P] [--max-nodes N]``.
Needs ``rabbitmq-server`` (Debian) and the ``metricq`` package.
"""

from __future__ import annotations

import argparse
import asyncio
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import psutil

REPO = Path(__file__).resolve().parents[1]
SRC = REPO / "src"
sys.path.insert(0, str(SRC))

from hdeem_watch.wire import protocol  # noqa: E402

CHANNELS = {"BLADE": 1000, "CPU0": 100, "CPU1": 100, "DDR_AB": 100, "DDR_CD": 100, "DDR_EF": 100, "DDR_GH": 100}
POLL_S = 0.04
PREFIX = "bench.hw"


def load_standin() -> Any:
    spec = importlib.util.spec_from_file_location("hdeem_watch_bench_standin", REPO / "tests/metricq/standin.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


# --- the synthetic nodes (run as a child process: ``--role publish``) ---------------------------

def publish(endpoints: list[str], nodes: int, seconds: float, start_at: float, counts_file: str) -> None:
    """Publish ``nodes`` nodes' samples (node i on endpoint i % len) from ``start_at`` for ``seconds``."""
    import zmq

    context = zmq.Context()
    sockets = []
    for endpoint in endpoints:
        sock = context.socket(zmq.PUB)
        sock.setsockopt(zmq.SNDHWM, 100_000)
        sock.bind(endpoint)
        sockets.append(sock)
    encoders = {(n, ch): protocol.SamplesEncoder(f"node{n:03d}", ch, rate) for n in range(nodes)
                for ch, rate in CHANNELS.items()}
    seqs = dict.fromkeys(encoders, 0)
    sent = dict.fromkeys(encoders, 0)
    rng = np.random.default_rng(1)
    while time.time() < start_at:
        time.sleep(0.01)
    t_next = time.monotonic()
    t_wall0 = time.time_ns()
    per_batch = {ch: int(rate * POLL_S) for ch, rate in CHANNELS.items()}
    batch = 0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        t_next += POLL_S
        for (n, ch), encoder in encoders.items():
            k = per_batch[ch]
            step = 1_000_000_000 // CHANNELS[ch]
            first = t_wall0 + batch * k * step
            t = first + step * np.arange(1, k + 1, dtype=np.int64)
            p = rng.random(k) * 10
            frames = encoder.frames(seqs[(n, ch)], time.time_ns(), t, p, 0.0, "ok")
            sockets[n % len(sockets)].send_multipart(frames)
            seqs[(n, ch)] += 1
            sent[(n, ch)] += k
        batch += 1
        time.sleep(max(0.0, t_next - time.monotonic()))
    Path(counts_file).write_text(json.dumps({f"node{n:03d}/{ch}": v for (n, ch), v in sent.items()}))
    time.sleep(1.0)
    for sock in sockets:
        sock.close(linger=1000)
    context.term()


# --- the measurement ------------------------------------------------------------------------------

def expected_metrics(nodes: int) -> list[str]:
    names = []
    for n in range(nodes):
        for ch in CHANNELS:
            path = "dram." + ch[4:].lower() if ch.startswith("DDR_") else ch.lower()
            names.append(f"{PREFIX}.node{n:03d}.{path}.power")
            if ch.startswith("DDR_"):
                names.append(f"{PREFIX}.node{n:03d}.{path}.above_baseline.power")
    return names


def start_source(server: str, endpoints: list[str], status: Path, flush_s: float) -> subprocess.Popen[bytes]:
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    args = [sys.executable, "-m", "hdeem_watch", "metricq-source", "--server", server, "--prefix", PREFIX,
            "--token", f"source-bench-{status.stem}", "--status-file", str(status), "--status-interval", "1",
            "--flush-interval", str(flush_s)]
    for endpoint in endpoints:
        args += ["--connect", endpoint]
    return subprocess.Popen(args, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def _status(path: Path) -> dict[str, Any]:
    try:
        return dict(json.loads(path.read_text()))
    except (OSError, ValueError):
        return {}


async def run_case(standin: Any, broker: Any, workdir: Path, nodes: int, sources: int, seconds: float,
                   flush_s: float) -> dict[str, Any]:
    """One run: ``nodes`` synthetic nodes over ``sources`` source processes; counts and CPU."""
    manager = standin.ManagerStandIn(broker.url)
    await manager.connect()
    sink = standin.RecordingSink(broker.url)
    await sink.connect()
    metrics = expected_metrics(nodes)
    await sink.subscribe(metrics)
    case = workdir / f"n{nodes}"
    case.mkdir(exist_ok=True)
    groups = min(sources, nodes)
    endpoints = [f"ipc://{case}/pub{g}.sock" for g in range(groups)]
    counts = case / "counts.json"
    procs = [start_source(broker.url, [endpoints[g]], case / f"status{g}.json", flush_s) for g in range(groups)]
    deadline = time.monotonic() + 60
    while not all(_status(case / f"status{g}.json").get("broker") == "connected" for g in range(groups)):
        if time.monotonic() > deadline:
            raise RuntimeError("the sources did not connect within 60 s")
        await asyncio.sleep(0.2)
    start_at = time.time() + 2.0  # the publisher binds, the sources' SUB sockets reconnect to it
    endpoint_args = [a for e in endpoints for a in ("--endpoint", e)]
    publisher = subprocess.Popen([sys.executable, __file__, "--role", "publish", "--nodes", str(nodes),
                                  "--seconds", str(seconds), "--start-at", str(start_at), "--counts", str(counts),
                                  *endpoint_args])
    try:
        await asyncio.sleep(max(0.0, start_at - time.time()) + 1.0)
        cpu0 = [psutil.Process(p.pid).cpu_times() for p in procs]
        t0 = time.monotonic()
        await asyncio.sleep(max(1.0, seconds - 2.0))
        cpu1 = [psutil.Process(p.pid).cpu_times() for p in procs]
        elapsed = time.monotonic() - t0
        await asyncio.to_thread(publisher.wait, seconds + 60)
        last, stable_since = -1, time.monotonic()
        while time.monotonic() - stable_since < 3.0:  # drain: until the sink's count stops growing
            await asyncio.sleep(0.5)
            if sink.count != last:
                last, stable_since = sink.count, time.monotonic()
        published = json.loads(counts.read_text())
        expected = sum(v * (2 if key.split("/")[1].startswith("DDR_") else 1) for key, v in published.items())
        statuses = [json.loads((case / f"status{g}.json").read_text()) for g in range(groups)]
    finally:
        for p in procs:
            p.terminate()
        for p in procs:
            p.wait(timeout=30)
        if publisher.poll() is None:
            publisher.kill()
        await sink.stop(silent=True)
        await manager.stop(silent=True)
    cpu = [(b.user + b.system - a.user - a.system) / elapsed * 100 for a, b in zip(cpu0, cpu1)]
    return {"nodes": nodes, "sources": groups, "seconds": seconds, "expected_points": expected,
            "received_points": sink.count, "lost_points": expected - sink.count,
            "stream_gaps": sum(s["stream_gaps"] for s in statuses),
            "dropped": sum(s["points_dropped"] for s in statuses),
            "source_cpu_percent": cpu, "samples_per_s_per_node": sum(published.values()) / nodes / seconds}


async def bench(args: argparse.Namespace) -> dict[str, Any]:
    standin = load_standin()
    results: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="bench-metricq-") as tmp:
        workdir = Path(tmp)
        broker = standin.Broker(workdir / "rabbitmq")
        broker.start()
        try:
            one = await run_case(standin, broker, workdir, 1, 1, args.seconds, args.flush_interval)
            results["cpu"] = one
            print(f"cpu: one node ({one['samples_per_s_per_node']:.0f} samples/s) through one source: "
                  f"{one['source_cpu_percent'][0]:.2f} % of one core (target <= 5 %, ratio "
                  f"{5 / max(one['source_cpu_percent'][0], 1e-9):.2f}); lost {one['lost_points']}", flush=True)
            ladder = [n for n in ((1, 4, 8) if args.quick else (1, 4, 8, 16, 32, 64)) if n <= args.max_nodes]
            if args.nodes_list:
                ladder = [int(n) for n in args.nodes_list.split(",")]
            ceiling = 0
            results["nodes"] = []
            for n in ladder:
                r = await run_case(standin, broker, workdir, n, args.sources, args.seconds, args.flush_interval)
                results["nodes"].append(r)
                print(f"nodes: {n:3d} nodes over {r['sources']} sources, {args.seconds:g} s: "
                      f"{r['received_points']}/{r['expected_points']} points, lost {r['lost_points']} "
                      f"(ZeroMQ gaps {r['stream_gaps']}, buffer drops {r['dropped']}); source CPU "
                      + ", ".join(f"{c:.1f} %" for c in r["source_cpu_percent"]), flush=True)
                if r["lost_points"] != 0:
                    break
                ceiling = n
            results["ceiling_nodes"] = ceiling
            print(f"ceiling: {ceiling} nodes with 0 lost points (target 64, ratio {ceiling / 64:.2f})")
        finally:
            broker.close()
    return results


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="10 s per case, up to 8 nodes")
    parser.add_argument("--seconds", type=float, help="seconds per case (default 60, --quick 10)")
    parser.add_argument("--sources", type=int, default=4, help="source processes sharing the nodes (default 4)")
    parser.add_argument("--max-nodes", type=int, default=64)
    parser.add_argument("--nodes-list", default="", help="comma-separated node counts instead of the ladder")
    parser.add_argument("--flush-interval", type=float, default=0.2, help="the sources' --flush-interval")
    parser.add_argument("--json", action="store_true", help="print the results as JSON at the end")
    parser.add_argument("--role", default="bench", help=argparse.SUPPRESS)
    parser.add_argument("--nodes", type=int, default=1, help=argparse.SUPPRESS)
    parser.add_argument("--start-at", type=float, default=0.0, help=argparse.SUPPRESS)
    parser.add_argument("--counts", default="", help=argparse.SUPPRESS)
    parser.add_argument("--endpoint", action="append", default=[], help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.seconds is None:
        args.seconds = 10.0 if args.quick else 60.0
    if args.role == "publish":
        publish(args.endpoint, args.nodes, args.seconds, args.start_at, args.counts)
        return 0
    results = asyncio.run(bench(args))
    if args.json:
        print(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
