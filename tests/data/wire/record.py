"""Record real wire messages of a daemon into this folder (see README.md).

Usage (from a checkout whose daemon is to be recorded)::

    PYTHONPATH=<checkout>/src python3 tests/data/wire/record.py tests/data/wire

Starts ``python3 -m hdeem_watch daemon --source sim --counters sim --speed 10`` with private ipc
sockets, subscribes to everything, drives a run, a SLURM job, a baseline measurement and a few
control requests (good and bad), and writes what it saw: ``stream.jsonl`` (one message a line, its
three frames in base64, at most a few per topic) and ``control.jsonl`` (each request frame and the
daemon's reply frame, in base64). Only pyzmq is used here, so the recording is independent of the
client code under test.
"""

from __future__ import annotations

import base64
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import zmq

PER_TOPIC = 3
SECONDS = 14.0


def _b64(frame: bytes) -> str:
    return base64.b64encode(frame).decode()


class Recorder:
    def __init__(self, pub: str, control: str) -> None:
        ctx = zmq.Context.instance()
        self.sub = ctx.socket(zmq.SUB)
        self.sub.setsockopt(zmq.SUBSCRIBE, b"hw1/")
        self.sub.connect(pub)
        self.dealer = ctx.socket(zmq.DEALER)
        self.dealer.connect(control)
        self.stream: list[list[bytes]] = []
        self.per_topic: dict[bytes, int] = {}
        self.control: list[tuple[bytes, bytes]] = []

    def drain(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            if self.sub.poll(50):
                frames = self.sub.recv_multipart()
                n = self.per_topic.get(frames[0], 0)
                if n < PER_TOPIC:
                    self.per_topic[frames[0]] = n + 1
                    self.stream.append(frames)

    def call(self, request: bytes | dict[str, Any]) -> dict[str, Any]:
        frame = request if isinstance(request, bytes) else json.dumps(request).encode()
        self.dealer.send_multipart([b"", frame])
        while not self.dealer.poll(100):
            self.drain(0.05)
        reply = self.dealer.recv_multipart()[-1]
        self.control.append((frame, reply))
        return dict(json.loads(reply))


def record(out: Path) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        pub, control = f"ipc://{tmp}/p.sock", f"ipc://{tmp}/c.sock"
        daemon = subprocess.Popen(
            [sys.executable, "-m", "hdeem_watch", "daemon", "--source", "sim", "--counters", "sim", "--speed", "10",
             "--pub", pub, "--control", control, "--state-dir", f"{tmp}/state", "--node", "rec1"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            rec = Recorder(pub, control)
            rec.call({"id": 1, "op": "ping"})
            rec.drain(2.0)
            rec.call({"id": 2, "op": "status"})
            started = rec.call({"id": 3, "op": "run.start", "args": {"kernel": "triad", "threads": 4,
                                                                      "elements": 2**24}})
            rec.drain(2.0)
            rec.call({"id": 4, "op": "run.stop", "args": {"run_id": started["result"]["run_id"]}})
            rec.call({"id": 5, "op": "job.start", "args": {"job_id": "4242", "user": os.environ.get("USER", "root"),
                                                            "uid": os.getuid(), "nodes": ["rec1"]}})
            rec.drain(1.0)
            rec.call({"id": 6, "op": "job.stop", "args": {"job_id": 4242, "exit_code": "0:0"}})
            rec.call({"id": "m", "op": "baseline.measure", "args": {"seconds": 1}})
            for rid, op in enumerate(("runs.list", "calib.get", "baseline.get", "job.list"), start=7):
                rec.call({"id": rid, "op": op})
            rec.call({"id": 11, "op": "no.such.op"})
            rec.call(b"{not json")
            rec.call({"id": 12, "op": "run.stop", "args": {"run_id": "nope"}})
            rec.drain(SECONDS)
        finally:
            daemon.send_signal(signal.SIGTERM)
            daemon.wait(timeout=30)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "stream.jsonl", "w", encoding="utf-8") as f:
        for frames in rec.stream:
            f.write(json.dumps({"frames": [_b64(x) for x in frames]}) + "\n")
    with open(out / "control.jsonl", "w", encoding="utf-8") as f:
        for request, reply in rec.control:
            f.write(json.dumps({"request": _b64(request), "reply": _b64(reply)}) + "\n")
    kinds = sorted({frames[0].split(b"/")[2].decode() for frames in rec.stream})
    print(f"{len(rec.stream)} stream messages of kinds {kinds}, {len(rec.control)} control exchanges")


if __name__ == "__main__":
    record(Path(sys.argv[1] if len(sys.argv) > 1 else os.path.dirname(os.path.abspath(__file__))))
