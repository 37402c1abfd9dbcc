"""SLURM job windows in a real daemon process over its sockets: job.start/job.stop/job.list, the
energy equal to the streamed samples' integral, and a job that survives ``kill -9``."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from typing import Any

import numpy as np
import pytest

from hdeem_watch.wire import protocol


def _integral(stream: list[protocol.Message], channel: str, first: int, last: int) -> float:
    """Energy of the streamed samples of ``channel`` with first < t <= last."""
    messages = [m for m in stream if m.kind == "samples" and m.channel == channel]
    period_s = 1.0 / messages[0].header["rate_hz"]
    t = np.concatenate([m.samples()[0] for m in messages])
    p = np.concatenate([m.samples()[1] for m in messages])
    # The stream covers the segment: from the first sample after ``first`` to ``last``.
    assert t.min() <= first + 1.5e9 * period_s and t.max() >= last, channel
    return float(p[(t > first) & (t <= last)].sum()) * period_s


def _wait_for(predicate: Any, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.05)


@pytest.mark.slow
def test_a_job_over_sockets_survives_kill_9(daemon_factory: Any, receive: Any) -> None:
    """A job's record equals the integral of the streamed samples over each of its segments, before
    and after the daemon was kill -9ed mid-job and restarted; job.list and the status show it."""
    d = daemon_factory(HDEEM_WATCH_JOB_CHECKPOINT_S="0.2", HDEEM_WATCH_HEARTBEAT_S="0.2").start()
    sub = d.subscriber(protocol.subscription(d.node))
    time.sleep(0.3)
    with d.client(timeout_s=10.0) as client:
        started = client.call("job.start", {"job_id": "31", "user": "alice", "uid": 1000, "nodes": ["testnode"],
                                            "cpus": 2})
        assert started["state"] == "running"
        assert [j["job_id"] for j in client.call("status")["jobs"]] == ["31"]
        time.sleep(0.5)
        live = client.call("job.get", {"job_id": "31"})
        assert live["dram_energy_j"] > 0 and live["segments"][0]["open"]
        first_stream = receive(sub, 0.4)
    d.kill9()
    first_stream += receive(sub, 0.3)  # what was on its way when the daemon died
    d.start()
    with d.client(timeout_s=10.0) as client:
        _wait_for(lambda: bool(client.call("status")["jobs"]), 5.0)
        time.sleep(0.5)
        record = client.call("job.stop", {"job_id": "31", "exit_code": 0})
        second_stream = receive(sub, 0.3)
        listed = client.call("job.list", {"user": "alice"})["jobs"]
    sub.close()
    assert record["state"] == "done" and len(record["segments"]) == 2 and record["status"].startswith("gap:")
    assert record["unmeasured_s"] > 0 and [j["job_id"] for j in listed] == ["31"]
    for segment, stream in zip(record["segments"], (first_stream, second_stream), strict=True):
        for channel, (first, last) in segment["samples_ns"].items():
            if channel.startswith("DDR"):
                expected = _integral(stream, channel, first, last)
                assert segment["energy_j"][channel] == pytest.approx(expected, rel=1e-9, abs=1e-9), channel
    assert record["dram_energy_j"] == pytest.approx(
        sum(s["energy_j"][c] for s in record["segments"] for c in s["energy_j"] if c.startswith("DDR")), rel=1e-12)
    cli = subprocess.run([sys.executable, "-m", "hdeem_watch", "jobs", "--connect", d.control, "--job", "31", "--json"],
                         capture_output=True, text=True, timeout=60, env=d.env)
    assert cli.returncode == 0, cli.stderr
    shown = json.loads(cli.stdout)["nodes"][0]
    assert shown["ok"] and shown["node"] == "testnode" and shown["jobs"][0]["dram_energy_j"] == record["dram_energy_j"]


@pytest.mark.slow
def test_a_retried_job_start_gets_the_record_again_at_once(daemon_factory: Any) -> None:
    """A retried Prolog (job.start of a job already open) gets the open record again at once, not
    a 10 s wait: the deferred reply was sent before the server knew where to send it."""
    d = daemon_factory().start()
    args = {"job_id": "555", "user": "alice", "uid": 1000, "nodes": ["testnode"], "cpus": 1}
    with d.client(timeout_s=10.0) as client:
        first = client.call("job.start", args)
        for _ in range(3):
            began = time.monotonic()
            again = client.call("job.start", args)
            assert time.monotonic() - began < 1.0
            assert again["job_id"] == "555" and again["state"] == "running"
            assert again["t_start_ns"] == first["t_start_ns"]
        assert [j["job_id"] for j in client.call("status")["jobs"]] == ["555"]
