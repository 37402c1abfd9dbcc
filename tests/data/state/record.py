"""Record the JSON rows a real daemon stores (its SQLite state file) into this folder (README.md).

Usage (from a checkout whose daemon is to be recorded)::

    cd /tmp && PYTHONPATH=/path/to/checkout/src python3 /path/to/tests/data/state/record.py /path/to/tests/data/state

Starts the simulated node ``rec1`` (``--source sim --counters sim --speed 10``, private ipc
sockets), makes three runs and one job over its control socket (pyzmq only), stops it with
SIGTERM and writes every row of the ``runs``, ``fits`` and ``jobs`` tables to ``rows.jsonl``: one
row a line, ``{"table": ..., "key": ..., "json": <the stored text, unchanged>}``.
"""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import zmq


def _call(dealer: zmq.Socket, request: dict[str, Any]) -> dict[str, Any]:
    dealer.send_multipart([b"", json.dumps(request).encode()])
    if not dealer.poll(30_000):
        raise SystemExit(f"no reply to {request['op']}")
    return dict(json.loads(dealer.recv_multipart()[-1]))


def _session(control: str) -> None:
    dealer = zmq.Context.instance().socket(zmq.DEALER)
    dealer.connect(control)
    deadline = time.monotonic() + 30
    while _call(dealer, {"id": 0, "op": "ping"}).get("result") is None and time.monotonic() < deadline:
        time.sleep(0.2)
    for i, (kernel, threads) in enumerate((("triad", 4), ("copy", 8), ("idle", 1)), start=1):
        run = _call(dealer, {"id": i, "op": "run.start",
                             "args": {"kernel": kernel, "threads": threads, "elements": 2**24}})["result"]["run"]
        time.sleep(1.5)
        _call(dealer, {"id": 10 + i, "op": "run.stop", "args": {"run_id": run["run_id"]}})
    _call(dealer, {"id": 20, "op": "job.start", "args": {"job_id": "4242", "user": "rec", "uid": 1000,
                                                         "nodes": ["rec1"], "cpus": 4}})
    time.sleep(1.5)
    _call(dealer, {"id": 21, "op": "job.stop", "args": {"job_id": "4242", "exit_code": "0:0"}})
    _call(dealer, {"id": 22, "op": "job.start", "args": {"job_id": "4243", "user": "rec", "nodes": "rec[1-2]"}})
    time.sleep(3.0)  # the runs' models and refits land in the store


def record(out: Path) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        control = f"ipc://{tmp}/c.sock"
        daemon = subprocess.Popen(
            [sys.executable, "-m", "hdeem_watch", "daemon", "--source", "sim", "--counters", "sim", "--speed", "10",
             "--pub", f"ipc://{tmp}/p.sock", "--control", control, "--state-dir", f"{tmp}/state", "--node", "rec1"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            _session(control)
        finally:
            daemon.send_signal(signal.SIGTERM)
            daemon.wait(timeout=30)
        state = next(Path(tmp, "state").rglob("*.db"))
        db = sqlite3.connect(state)
        rows = [("runs", k, v) for k, v in db.execute("SELECT run_id, record FROM runs ORDER BY seq")]
        rows += [("fits", str(k), v) for k, v in db.execute("SELECT id, fit FROM fits ORDER BY id") if v]
        rows += [("jobs", k, v) for k, v in db.execute("SELECT job_key, record FROM jobs ORDER BY t_start_ns")]
        db.close()
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "rows.jsonl", "w", encoding="utf-8") as f:
        for table, key, text in rows:
            f.write(json.dumps({"table": table, "key": key, "json": text}) + "\n")
    print(f"{len(rows)} rows: " + ", ".join(f"{t} {sum(1 for r in rows if r[0] == t)}" for t in ("runs", "fits", "jobs")))


if __name__ == "__main__":
    record(Path(sys.argv[1] if len(sys.argv) > 1 else os.path.dirname(os.path.abspath(__file__))))
