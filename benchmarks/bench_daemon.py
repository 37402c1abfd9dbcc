"""Benchmark of the node daemon: CPU share, lost samples and latency at full HDEEM rate; publishing ceiling.

Phases:

1. **steady**: the daemon as a real process with the simulated node at speed 1 — HDEEM's full rate,
   BLADE at 1000 Sa/s and six channels at 100 Sa/s — and 4 subscriber processes for ``--seconds``
   (default 60, ``--quick`` 10). Reported: the daemon's CPU share of one core (target ≤ 2 %), beside
   three baselines: an idle Python process with the same imports, a process that only wakes at the
   poll rate, and one that also hands one poll's pre-built messages (7 channels, the daemon's sizes)
   to ZeroMQ for the same number of subscribers (the transport's floor: what any daemon polling at
   this rate pays on this machine before doing any work); samples lost by the subscribers
   (sequence gaps and missing timestamps; target 0); p50/p99 sensor→subscriber latency (receive wall
   time minus the sample's own timestamp, the end of its interval; target p99 ≤ 50 ms).
2. **ceiling (publisher)**: the daemon's publisher (protocol encoding + XPUB) flooding batches of
   ``--batch`` samples to 4 subscriber processes for a few seconds: samples/s received by every
   subscriber (target ≥ 1 M/s).
3. **ceiling (daemon)**: the whole daemon with the sim at ``--flood-speed`` (1 600 Sa/s × speed
   generated) and one subscriber: samples/s delivered and lost.
4. **control load**: 100 stored runs (copies of one real record, ~46 KB each), the daemon at full
   HDEEM rate with one subscriber, and ``--control-clients`` (default 50) threads asking in a loop for
   ``runs.list`` (100 summaries, then 20 full records), ``status``, ``calib.get``, ``baseline.get``:
   the stream's p99 latency (target ≤ 50 ms) and the requests/s served (``--only-load`` runs just this).

Usage: ``python3 benchmarks/bench_daemon.py [--quick] [--seconds S] [--json]``. Prints each figure,
its target and the ratio (figure/target, or target/figure for "at most" targets: ≥ 1 is met).
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import psutil
import zmq

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from hdeem_watch.config import DaemonSettings  # noqa: E402
from hdeem_watch.wire import protocol  # noqa: E402
from hdeem_watch.wire.client import ControlClient, DaemonUnreachable  # noqa: E402


def _env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("HDEEM_WATCH_")}
    env["PYTHONPATH"] = str(ROOT / "src") + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env


def start_daemon(directory: Path, speed: float, *extra: str) -> tuple[subprocess.Popen[bytes], str, str]:
    """Start ``hdeem-watch daemon --source sim`` on ipc sockets in ``directory``; wait until it answers."""
    pub, control = f"ipc://{directory}/p.sock", f"ipc://{directory}/c.sock"
    proc = subprocess.Popen(
        [sys.executable, "-m", "hdeem_watch", "daemon", "--source", "sim", "--speed", str(speed), "--pub", pub,
         "--control", control, "--state-dir", str(directory / "state"), "--node", "bench", "--log-level",
         "warning", *extra],
        env=_env(), stdout=subprocess.DEVNULL, stderr=open(directory / "daemon.err", "ab"),  # noqa: SIM115
    )
    deadline = time.monotonic() + 60
    with ControlClient(control, timeout_s=1.0) as client:
        while True:
            try:
                # Ready when the worker has built the model (its imports cost seconds of CPU).
                if not client.call("calib.get").get("loading"):
                    return proc, pub, control
                time.sleep(0.1)
            except DaemonUnreachable:
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError((directory / "daemon.err").read_text()) from None
                time.sleep(0.1)


def subscriber(pub: str, seconds: float, ready: Any, results: Any, prefix: bytes) -> None:
    """A subscriber process: counts samples, gaps, missing timestamps and per-sample latency."""
    sock = zmq.Context.instance().socket(zmq.SUB)
    sock.setsockopt(zmq.RCVHWM, 1_000_000)
    sock.connect(pub)
    sock.setsockopt(zmq.SUBSCRIBE, prefix)
    ready.put(os.getpid())
    tracker = protocol.GapTracker()
    last_t: dict[str, int] = {}
    missing = 0
    samples = 0
    latencies: list[np.ndarray] = []
    first = None
    poller = zmq.Poller()
    poller.register(sock, zmq.POLLIN)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if not poller.poll(100):
            continue
        frames = sock.recv_multipart(copy=True)
        now = time.time_ns()
        msg = protocol.decode(frames)
        if msg.kind != "samples":
            continue
        if first is None:
            first = time.monotonic()
        tracker.observe(msg.topic, msg.seq)
        t, _ = msg.samples()
        if t.size:
            period = int(msg.header["dt_ns"])
            previous = last_t.get(msg.topic)
            steps = np.diff(t, prepend=previous) if previous is not None else np.diff(t)
            missing += int(np.sum(np.maximum(np.rint(steps / period) - 1, 0)))
            last_t[msg.topic] = int(t[-1])
            # Latency in the steady state only: the first batches after subscribing were collected at the
            # daemon's idle poll period (0.25 s) before it saw the subscription.
            if time.monotonic() - first >= WARMUP_S:
                latencies.append((now - t) / 1e6)
            samples += int(t.size)
    elapsed = time.monotonic() - first if first is not None else float("nan")
    lat = np.concatenate(latencies) if latencies else np.array([np.nan])
    results.put({"samples": samples, "seconds": elapsed, "missed_messages": tracker.missed,
                 "missing_samples": missing, "p50_ms": float(np.percentile(lat, 50)),
                 "p99_ms": float(np.percentile(lat, 99)), "max_ms": float(np.max(lat))})
    sock.close(0)


#: Seconds after a subscriber's first samples message before its latencies count (the CPU window's warm-up).
WARMUP_S = 2.0


def run_subscribers(pub: str, n: int, seconds: float, prefix: bytes = b"hw1/") -> tuple[list[Any], Any, Any]:
    ctx = mp.get_context("spawn")
    ready, results = ctx.Queue(), ctx.Queue()
    procs = [ctx.Process(target=subscriber, args=(pub, seconds, ready, results, prefix)) for _ in range(n)]
    for p in procs:
        p.start()
    for _ in procs:
        ready.get(timeout=60)
    return procs, ready, results


def cpu_seconds(proc: psutil.Process) -> float:
    times = proc.cpu_times()
    return float(times.user + times.system)


def idle_baseline_cpu(seconds: float) -> float:
    """CPU share (% of one core) of an idle Python process holding the daemon's imports."""
    code = "import time, numpy, scipy, zmq, psutil, hdeem_watch.daemon.service\nprint('up', flush=True)\ntime.sleep(1e6)"
    return _baseline_cpu([sys.executable, "-c", code], seconds)


def _baseline_cpu(argv: list[str], seconds: float, warmup_s: float = 0.0) -> float:
    """CPU share (% of one core) of a baseline process over ``seconds``, ``warmup_s`` after it prints
    its first line (its own CPU, not its children's; they are killed with it)."""
    proc = subprocess.Popen(argv, env=_env(), stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        proc.stdout.readline()
        ps = psutil.Process(proc.pid)
        time.sleep(warmup_s)
        c0, t0 = cpu_seconds(ps), time.monotonic()
        time.sleep(seconds)
        return 100 * (cpu_seconds(ps) - c0) / (time.monotonic() - t0)
    finally:
        for child in psutil.Process(proc.pid).children(recursive=True):
            child.kill()
        proc.kill()
        proc.wait()


WAKE_LOOP = """
import sys, time, zmq
ctx = zmq.Context()
a = ctx.socket(zmq.XPUB); a.bind(sys.argv[1] + "/w1.sock")
b = ctx.socket(zmq.ROUTER); b.bind(sys.argv[1] + "/w2.sock")
poller = zmq.Poller(); poller.register(a, zmq.POLLIN); poller.register(b, zmq.POLLIN)
interval_ms = float(sys.argv[2]) * 1000
print("up", flush=True)
while True:
    poller.poll(interval_ms)
"""


SEND_LOOP = """
import subprocess, sys, time, zmq
import numpy as np
from hdeem_watch.daemon.shell.publisher import Publisher, daemon_context
from hdeem_watch.sources.base import hdeem_channel_infos
endpoint, interval_s, subscribers = sys.argv[1], float(sys.argv[2]), int(sys.argv[3])
ctx = daemon_context()  # the daemon's transport: its I/O thread under SCHED_BATCH
publisher = Publisher(ctx, endpoint + "/s1.sock", node="bench")
control = ctx.socket(zmq.ROUTER); control.bind(endpoint + "/s2.sock")
sub = ("import sys, zmq\\ns = zmq.Context().socket(zmq.SUB); s.connect(sys.argv[1]); "
       "s.setsockopt(zmq.SUBSCRIBE, b'hw1/')\\nwhile True: s.recv_multipart()")
children = [subprocess.Popen([sys.executable, "-c", sub, publisher.endpoint]) for _ in range(subscribers)]
seen = 0
while seen < subscribers:  # every subscriber is connected and subscribed
    seen += publisher.handle_subscriptions() if publisher.socket.poll(100) else 0
# The daemon's messages of one poll, built once by its own encoder: each channel's samples of one period.
messages = []
for info in hdeem_channel_infos():
    n = max(1, round(info.rate_hz * interval_s))
    t = np.arange(n, dtype=np.int64) * round(1e9 / info.rate_hz)
    messages.append(publisher.samples_message(info.name, info.rate_hz, t, np.full(n, 5.0), 1.0, "ok", 0))
poller = zmq.Poller()
poller.register(control, zmq.POLLIN)
poller.register(publisher.socket, zmq.POLLIN)
interval_ns = round(interval_s * 1e9)
deadline = time.monotonic_ns()
print("up", flush=True)
while True:
    deadline += interval_ns
    for sock, _event in poller.poll(max(0, -(-(deadline - time.monotonic_ns()) // 1_000_000))):
        if sock is publisher.socket:
            publisher.handle_subscriptions()
    publisher.send_all(messages)
"""


def send_baseline_cpu(seconds: float, interval_s: float, subscribers: int) -> float:
    """CPU share of a process that only wakes at the poll rate and hands one poll's pre-built messages
    (one per channel, the daemon's sizes) to ZeroMQ, in the daemon's context, for ``subscribers``
    subscribers: the transport's floor."""
    with tempfile.TemporaryDirectory(prefix="hws-") as tmp:
        argv = [sys.executable, "-c", SEND_LOOP, f"ipc://{tmp}", str(interval_s), str(subscribers)]
        return _baseline_cpu(argv, seconds, warmup_s=1.0)


def wake_baseline_cpu(seconds: float, interval_s: float) -> float:
    """CPU share of a process that only wakes at the daemon's poll rate (zmq poll on two sockets)."""
    with tempfile.TemporaryDirectory(prefix="hww-") as tmp:
        return _baseline_cpu([sys.executable, "-c", WAKE_LOOP, f"ipc://{tmp}", str(interval_s)], seconds)


def steady(seconds: float, subscribers: int, poll_interval_s: float) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="hwb-") as tmp:
        proc, pub, _ = start_daemon(Path(tmp), 1.0, "--poll-interval", str(poll_interval_s))
        try:
            ps = psutil.Process(proc.pid)
            time.sleep(1.0)
            c0, t0 = cpu_seconds(ps), time.monotonic()
            time.sleep(min(seconds, 10.0))  # nobody watches: the daemon polls at its idle period
            unwatched = 100 * (cpu_seconds(ps) - c0) / (time.monotonic() - t0)
            procs, _ready, results = run_subscribers(pub, subscribers, seconds + 4)
            time.sleep(WARMUP_S)  # warm-up
            c0, t0 = cpu_seconds(ps), time.monotonic()
            time.sleep(seconds)
            cpu = 100 * (cpu_seconds(ps) - c0) / (time.monotonic() - t0)
            rss = ps.memory_info().rss
            subs = [results.get(timeout=60) for _ in procs]
            for p in procs:
                p.join(timeout=30)
        finally:
            proc.terminate()
            proc.wait(timeout=30)
    return {
        "cpu_percent": cpu, "cpu_percent_unwatched": unwatched, "rss_bytes": rss,
        "lost_samples": sum(s["missing_samples"] for s in subs),
        "lost_messages": sum(s["missed_messages"] for s in subs),
        "p50_ms": max(s["p50_ms"] for s in subs), "p99_ms": max(s["p99_ms"] for s in subs),
        "max_ms": max(s["max_ms"] for s in subs),
        "rate_per_subscriber": float(np.mean([s["samples"] / s["seconds"] for s in subs])),
    }


def publisher_ceiling(seconds: float, batch: int, subscribers: int) -> dict[str, Any]:
    """Flood the daemon's Publisher with large batches; samples/s every subscriber received."""
    from hdeem_watch.daemon.shell.publisher import Publisher

    with tempfile.TemporaryDirectory(prefix="hwc-") as tmp:
        endpoint = f"ipc://{tmp}/flood.sock"
        ctx = zmq.Context()
        publisher = Publisher(ctx, endpoint, node="bench", sndhwm=1000)
        procs, _ready, results = run_subscribers(endpoint, subscribers, seconds + 2.0)
        time.sleep(0.5)
        t = np.arange(batch, dtype=np.int64)
        p = np.random.default_rng(0).normal(5.0, 0.5, batch)
        sent = 0
        energy = 0.0
        end = time.monotonic() + seconds
        start = time.monotonic()
        while time.monotonic() < end:
            for channel in ("BLADE", "CPU0", "DDR_AB"):
                energy += 1.0
                publisher.publish_samples(channel, rate_hz=1e6, t_wall_ns=t + sent, power_w=p, energy_j=energy,
                                          status="ok")
                sent += batch
        elapsed = time.monotonic() - start
        subs = [results.get(timeout=60) for _ in procs]
        for proc in procs:
            proc.join(timeout=30)
        publisher.close()
        ctx.term()
    received = [s["samples"] / s["seconds"] for s in subs]
    return {"sent_per_s": sent / elapsed, "received_per_s_min": min(received),
            "received_per_s_total": sum(received), "lost_messages": sum(s["missed_messages"] for s in subs)}


#: Stored runs before the control load (each a real record of ~46 KB: model row and full fit).
LOAD_RUNS = 100
#: What each busy control client asks, in turn.
LOAD_OPS: tuple[tuple[str, dict[str, Any]], ...] = (
    ("runs.list", {"limit": 100}), ("status", {}), ("runs.list", {"full": True, "limit": 20}), ("calib.get", {}),
    ("baseline.get", {}),
)


def _seed_runs(directory: Path, n: int) -> int:
    """Make one real run on a sped-up daemon, then store ``n`` copies of its record; return its size."""
    from hdeem_watch.daemon.store.database import Store

    proc, _pub, control = start_daemon(directory, 20.0)
    try:
        with ControlClient(control, timeout_s=60.0) as client:
            run_id = client.call("run.start", {"kernel": "triad", "threads": 24, "elements": 1 << 24})["run_id"]
            time.sleep(0.2)
            record = client.call("run.stop", {"run_id": run_id})
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    store = Store(directory / "state" / "state.db")
    for i in range(2, n + 1):
        store.save_run({**record, "run_id": f"r{i}"})
    store.close()
    return len(protocol.dumps(record))


def _busy_client(control: str, stop: Any, counts: list[int], errors: list[str]) -> None:
    with ControlClient(control, timeout_s=30.0) as client:
        i = 0
        while not stop.is_set():
            op, args = LOAD_OPS[i % len(LOAD_OPS)]
            try:
                client.call(op, args)
                counts.append(1)
            except Exception as error:  # a benchmark counts errors, it does not stop
                errors.append(f"{op}: {error}")
            i += 1


def control_load(seconds: float, clients: int, runs: int = LOAD_RUNS) -> dict[str, Any]:
    """The stream's latency while ``clients`` busy control clients ask for runs, status and calibration."""
    import threading

    with tempfile.TemporaryDirectory(prefix="hwl-") as tmp:
        record_bytes = _seed_runs(Path(tmp), runs)
        proc, pub, control = start_daemon(Path(tmp), 1.0)
        try:
            procs, _ready, results = run_subscribers(pub, 1, seconds + WARMUP_S + 2.0)
            time.sleep(WARMUP_S)
            stop = threading.Event()
            counts: list[int] = []
            errors: list[str] = []
            threads = [threading.Thread(target=_busy_client, args=(control, stop, counts, errors), daemon=True)
                       for _ in range(clients)]
            t0 = time.monotonic()
            for thread in threads:
                thread.start()
            time.sleep(seconds)
            stop.set()
            for thread in threads:
                thread.join(timeout=60)
            elapsed = time.monotonic() - t0
            sub = results.get(timeout=120)
            procs[0].join(timeout=30)
        finally:
            proc.terminate()
            proc.wait(timeout=30)
    return {"clients": clients, "stored_runs": runs, "record_bytes": record_bytes,
            "requests_per_s": len(counts) / elapsed, "errors": len(errors), "first_error": errors[0] if errors else None,
            "p50_ms": sub["p50_ms"], "p99_ms": sub["p99_ms"], "max_ms": sub["max_ms"],
            "lost_samples": sub["missing_samples"], "lost_messages": sub["missed_messages"]}


def daemon_ceiling(seconds: float, speed: float) -> dict[str, Any]:
    """The whole daemon with a sped-up sim and one subscriber."""
    with tempfile.TemporaryDirectory(prefix="hwf-") as tmp:
        proc, pub, control = start_daemon(Path(tmp), speed)
        try:
            procs, _ready, results = run_subscribers(pub, 1, seconds + 2.0)
            ps = psutil.Process(proc.pid)
            c0, t0 = cpu_seconds(ps), time.monotonic()
            time.sleep(seconds)
            cpu = 100 * (cpu_seconds(ps) - c0) / (time.monotonic() - t0)
            sub = results.get(timeout=60)
            procs[0].join(timeout=30)
            with ControlClient(control, timeout_s=10.0) as client:
                status = client.call("status")
            source_gaps = sum(int(c["gaps"]) for c in status["channels"].values())
        finally:
            proc.terminate()
            proc.wait(timeout=30)
    return {"speed": speed, "generated_per_s": 1600.0 * speed, "delivered_per_s": sub["samples"] / sub["seconds"],
            "lost_samples": sub["missing_samples"], "lost_messages": sub["missed_messages"],
            "source_gaps": source_gaps, "cpu_percent": cpu}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="10 s steady phase, short ceilings")
    parser.add_argument("--seconds", type=float, help="steady phase length (default 60; quick 10)")
    parser.add_argument("--subscribers", type=int, default=4)
    parser.add_argument("--batch", type=int, default=100_000, help="samples per flood batch")
    parser.add_argument("--flood-speed", type=float, default=1000.0, help="sim speed of the daemon ceiling")
    parser.add_argument("--poll-interval", type=float, default=DaemonSettings().poll_interval_s, help="daemon poll period (s) of the steady phase")
    parser.add_argument("--control-clients", type=int, default=50, help="busy control clients of the load phase")
    parser.add_argument("--only-load", action="store_true", help="run only the control-load phase")
    parser.add_argument("--json", action="store_true", help="one JSON object on stdout")
    args = parser.parse_args(argv)
    seconds = args.seconds or (10.0 if args.quick else 60.0)
    flood_s = 3.0 if args.quick else 10.0

    results: dict[str, Any] = {"seconds": seconds, "subscribers": args.subscribers, "cpus": os.cpu_count(),
                               "poll_interval_s": args.poll_interval,
                               "load_average": os.getloadavg()}
    load_s = 10.0 if args.quick else 30.0
    if args.only_load:
        load = control_load(load_s, args.control_clients)
        print(f"control load: {load['clients']} busy clients, {load['stored_runs']} stored runs of "
              f"{load['record_bytes']} B, {load['requests_per_s']:.0f} requests/s, {load['errors']} errors; stream "
              f"p50 {load['p50_ms']:.1f} ms, p99 {load['p99_ms']:.1f} ms (target <= 50), max {load['max_ms']:.1f} ms, "
              f"lost samples {load['lost_samples']} / messages {load['lost_messages']}")
        return 0
    results["idle_process_cpu_percent"] = idle_baseline_cpu(min(seconds, 10.0))
    results["wake_loop_cpu_percent"] = wake_baseline_cpu(min(seconds, 10.0), args.poll_interval)
    results["send_loop_cpu_percent"] = send_baseline_cpu(min(seconds, 20.0), args.poll_interval, args.subscribers)
    results["steady"] = steady(seconds, args.subscribers, args.poll_interval)
    results["publisher_ceiling"] = publisher_ceiling(flood_s, args.batch, args.subscribers)
    results["daemon_ceiling"] = daemon_ceiling(flood_s, args.flood_speed)
    results["control_load"] = control_load(load_s, args.control_clients)

    s, pc, dc, cl = results["steady"], results["publisher_ceiling"], results["daemon_ceiling"], results["control_load"]
    rows = [
        ("daemon CPU at full HDEEM rate, % of one core", s["cpu_percent"], "<= 2.0",
         2.0 / s["cpu_percent"] if s["cpu_percent"] > 0 else float("inf")),
        ("daemon CPU, nobody subscribed to samples (idle poll period 0.25 s), %", s["cpu_percent_unwatched"],
         "<= 2.0", 2.0 / s["cpu_percent_unwatched"] if s["cpu_percent_unwatched"] > 0 else float("inf")),
        ("  baseline: idle Python process with the same imports, %", results["idle_process_cpu_percent"], "-",
         None),
        ("  baseline: a process that only wakes at the poll rate (zmq poll), %", results["wake_loop_cpu_percent"],
         "-", None),
        (f"  baseline: the same + one poll's 7 messages to {args.subscribers} subscribers, %",
         results["send_loop_cpu_percent"], "-", None),
        ("lost samples (all subscribers)", s["lost_samples"] + s["lost_messages"], "0", None),
        ("p99 sensor->subscriber latency, ms", s["p99_ms"], "<= 50", 50.0 / s["p99_ms"]),
        ("  p50 latency, ms", s["p50_ms"], "-", None),
        ("samples/s per subscriber (1000 + 6 x 100 nominal)", s["rate_per_subscriber"], "1600",
         s["rate_per_subscriber"] / 1600.0),
        (f"publishing ceiling, samples/s received by each of {args.subscribers} subscribers",
         pc["received_per_s_min"], ">= 1e6", pc["received_per_s_min"] / 1e6),
        ("  publisher send rate, samples/s", pc["sent_per_s"], "-", None),
        (f"whole daemon, sim at speed {dc['speed']:g}: samples/s delivered", dc["delivered_per_s"],
         f"{dc['generated_per_s']:.0f} generated", dc["delivered_per_s"] / dc["generated_per_s"]),
        ("  its lost samples (of which lost at the source: the sim's 60 sim-s buffer) / lost messages / CPU %",
         f"{dc['lost_samples']} ({dc['source_gaps']}) / {dc['lost_messages']} / {dc['cpu_percent']:.0f}", "-", None),
        (f"p99 stream latency under {cl['clients']} busy control clients, ms", cl["p99_ms"], "<= 50",
         50.0 / cl["p99_ms"]),
        (f"  their requests/s ({cl['stored_runs']} stored runs of {cl['record_bytes']} B) / errors / lost samples",
         f"{cl['requests_per_s']:.0f} / {cl['errors']} / {cl['lost_samples'] + cl['lost_messages']}", "-", None),
    ]
    if args.json:
        from hdeem_watch.wire.protocol import dumps

        print(dumps(results).decode())  # strict JSON: NaN as null
        return 0
    print(f"bench_daemon: {seconds:g} s steady, poll every {args.poll_interval * 1000:g} ms, {args.subscribers} "
          f"subscribers, {os.cpu_count()} CPUs, load average {results['load_average'][0]:.2f}")
    for name, value, target, ratio in rows:
        shown = f"{value:,.3f}" if isinstance(value, float) else str(value)
        ratio_text = f"ratio {ratio:.2f}" if ratio is not None else ""
        print(f"{name:<72} {shown:>16}  target {target:<16} {ratio_text}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
