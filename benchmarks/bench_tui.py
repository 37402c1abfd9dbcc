"""TUI benchmark: frames/s and CPU share of ``hdeem-watch tui`` with 8 nodes × 7 channels live.

Eight wire-protocol publishers (``hdeem_watch.demo.fakenode.FakeNode``: BLADE at 1000 Sa/s, six
channels at 100 Sa/s, batches every 100 ms, heartbeat every second) run in one separate process
on real ipc sockets. The real ``hdeem-watch tui`` connects to all eight control endpoints inside a
real terminal (tmux, 120×40) and writes its own figures each second (``--stats``). After a
warm-up the benchmark takes the differences over the measuring window: frames painted per
second, the UI process's CPU seconds per second (share of one core), stream messages per second
and gaps (messages lost, from sequence numbers). It presses ``n`` every few seconds so node
switching is part of the load.

Targets (DESIGN.md §8): ≥ 10 frames/s and ≤ 20 % of one core.

Usage:
    python3 benchmarks/bench_tui.py [--quick] [--seconds S] [--fps N] [--nodes N]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

TARGET_FPS = 10.0
TARGET_CPU_SHARE = 0.20


def serve(directory: str, nodes: int) -> None:
    """Run ``nodes`` fake publishers until killed (the benchmark's load process)."""
    from hdeem_watch.demo.fakenode import FakeNode

    fakes = [
        FakeNode(f"node{i:02d}", f"ipc://{directory}/p{i}", f"ipc://{directory}/c{i}", seed=i).start_and_wait()
        for i in range(nodes)
    ]
    print("ready", flush=True)
    try:
        while True:
            time.sleep(3600)
    finally:
        for fake in fakes:
            fake.stop()


def measure(seconds: float, warmup_s: float, fps: float, nodes: int) -> dict[str, float]:
    """Start the load and the TUI, return the steady-state figures."""
    if shutil.which("tmux") is None:
        raise SystemExit("bench_tui: tmux is needed (it is the real terminal the UI paints into)")
    directory = tempfile.mkdtemp(prefix="hwb-", dir="/tmp")
    stats = Path(directory) / "stats.jsonl"
    session = f"hwbench-{uuid.uuid4().hex[:8]}"
    load = subprocess.Popen(
        [sys.executable, __file__, "--serve", directory, "--nodes", str(nodes)], stdout=subprocess.PIPE, text=True
    )
    try:
        assert load.stdout is not None
        if load.stdout.readline().strip() != "ready":
            raise SystemExit("bench_tui: the publishers did not start")
        connect = " ".join(f"--connect ipc://{directory}/c{i}" for i in range(nodes))
        command = f"{sys.executable} -m hdeem_watch tui {connect} --fps {fps:g} --stats {stats}"
        subprocess.run(["tmux", "new-session", "-d", "-s", session, "-x", "120", "-y", "40", command], check=True)
        end = time.monotonic() + warmup_s + seconds + 1.5
        while time.monotonic() < end:
            time.sleep(2.5)
            subprocess.run(["tmux", "send-keys", "-t", session, "n"], check=False)
        screen = subprocess.run(["tmux", "capture-pane", "-p", "-t", session], capture_output=True, text=True).stdout
        lines = [json.loads(line) for line in stats.read_text().splitlines() if line.strip()]
        if len(lines) < 3:
            raise SystemExit(f"bench_tui: too few stats lines ({len(lines)}); screen:\n{screen}")
        start = next((ln for ln in lines if ln["t_s"] >= lines[0]["t_s"] + warmup_s), lines[0])
        last = lines[-1]
        span = last["t_s"] - start["t_s"]
        load_cpu = _cpu_share(load.pid)
        return {
            "seconds": span,
            "fps": (last["frames"] - start["frames"]) / span,
            "cpu_share": (last["cpu_s"] - start["cpu_s"]) / span,
            "messages_per_s": (last["messages"] - start["messages"]) / span,
            "gaps": last["gaps"],
            "load_cpu_share": load_cpu,
            "live_on_screen": float("LIVE" in screen.splitlines()[0] if screen else 0.0),
        }
    finally:
        subprocess.run(["tmux", "kill-session", "-t", session], capture_output=True, check=False)
        load.terminate()
        load.wait(10)
        shutil.rmtree(directory, ignore_errors=True)


def _cpu_share(pid: int) -> float:
    try:
        import psutil

        proc = psutil.Process(pid)
        return proc.cpu_percent(interval=1.0) / 100.0
    except Exception:
        return float("nan")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="short run (8 s measured)")
    parser.add_argument("--seconds", type=float, default=30.0, help="measuring window")
    parser.add_argument("--fps", type=float, default=10.0, help="the TUI's --fps")
    parser.add_argument("--nodes", type=int, default=8)
    parser.add_argument("--serve", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve:
        serve(args.serve, args.nodes)
        return 0
    seconds = 8.0 if args.quick else args.seconds
    result = measure(seconds, warmup_s=4.0, fps=args.fps, nodes=args.nodes)
    rate = args.nodes * (1000 + 6 * 100)
    print(f"TUI with {args.nodes} nodes x 7 channels live ({rate} samples/s, {result['messages_per_s']:.0f} messages/s received), "
          f"{result['seconds']:.1f} s measured, --fps {args.fps:g}, terminal 120x40 (tmux)")
    print(f"  frames/s       {result['fps']:6.1f}   target >= {TARGET_FPS:g}    ratio {result['fps'] / TARGET_FPS:.2f}x")
    print(f"  CPU (one core) {100 * result['cpu_share']:5.1f} %  target <= {100 * TARGET_CPU_SHARE:g} %  "
          f"ratio {result['cpu_share'] / TARGET_CPU_SHARE:.2f} of budget")
    print(f"  wire gaps      {result['gaps']:6.0f}   (messages lost between publishers and UI)")
    print(f"  publishers' own CPU (separate process, not counted): {100 * result['load_cpu_share']:.1f} %")
    ok = result["fps"] >= TARGET_FPS * 0.95 and result["cpu_share"] <= TARGET_CPU_SHARE
    print("  PASS" if ok else "  BELOW TARGET")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
