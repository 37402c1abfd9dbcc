"""A job's DRAM energy through a real SLURM: sbatch → Prolog job.start → the daemon's window →
Epilog job.stop → the stored record, checked against the daemon's own streamed samples, also after
the daemon was ``kill -9``ed mid-job and restarted."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zmq

from hdeem_watch.wire import protocol

#: A real SLURM: slow, and on one xdist worker with the other SLURM tests (one munged, one
#: cluster at a time).
pytestmark = [pytest.mark.slurm, pytest.mark.slow, pytest.mark.xdist_group("slurm")]


class StreamRecorder:
    """Every message of the daemon's stream, received on a thread (reconnects by itself after a
    daemon restart, as any ZeroMQ subscriber)."""

    def __init__(self, endpoint: str) -> None:
        self.messages: list[protocol.Message] = []
        self._stop = threading.Event()
        self._sock = zmq.Context.instance().socket(zmq.SUB)
        self._sock.setsockopt(zmq.RCVHWM, 1_000_000)
        self._sock.setsockopt(zmq.LINGER, 0)
        self._sock.connect(endpoint)
        self._sock.setsockopt(zmq.SUBSCRIBE, b"hw1/")
        self._thread = threading.Thread(target=self._receive, daemon=True)
        self._thread.start()

    def _receive(self) -> None:
        poller = zmq.Poller()
        poller.register(self._sock, zmq.POLLIN)
        while not self._stop.is_set():
            if poller.poll(50):
                self.messages.append(protocol.decode(self._sock.recv_multipart()))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self._sock.close()

    def integral(self, channel: str, first: int, last: int) -> float:
        """Energy of the streamed samples of ``channel`` with first < t <= last (each sample once)."""
        messages = [m for m in self.messages if m.kind == "samples" and m.channel == channel]
        period_s = 1.0 / messages[0].header["rate_hz"]
        t = np.concatenate([m.samples()[0] for m in messages])
        p = np.concatenate([m.samples()[1] for m in messages])
        t, index = np.unique(t, return_index=True)
        p = p[index]
        inside = (t > first) & (t <= last)
        assert inside.sum() == round((last - first) * 1e-9 / period_s), f"{channel}: samples missing from the stream"
        return float(p[inside].sum()) * period_s


@pytest.fixture
def daemon(slurm: Any) -> Iterator[dict[str, Any]]:
    """The node daemon (started as systemd would, from its config file) and a stream recorder."""
    state = {"proc": slurm.start_daemon()}
    recorder = StreamRecorder(slurm.pub)
    state["stream"] = recorder
    time.sleep(0.5)  # the subscription reaches the daemon
    yield state
    recorder.close()
    proc = state["proc"]
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=20)


def _jobs_cli(slurm: Any, *args: str) -> dict[str, Any]:
    env = {**slurm.env, "HDEEM_WATCH_CONFIG": str(slurm.daemon_config)}
    proc = subprocess.run([sys.executable, "-m", "hdeem_watch", "jobs", *args, "--json"], capture_output=True,
                          text=True, env=env, timeout=60, check=False)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return json.loads(proc.stdout)  # type: ignore[no-any-return]


def _sbatch(slurm: Any, script: str) -> str:
    path = slurm.root / f"job-{time.monotonic_ns()}.sh"
    path.write_text("#!/bin/sh\n" + script)
    env = {**slurm.env, "HDEEM_WATCH_CONFIG": str(slurm.daemon_config), "HDEEM_WATCH_PYTHON": sys.executable,
           "HDEEM_WATCH_HOOK_CONF": str(slurm.hook_conf)}
    proc = subprocess.run(["sbatch", "--parsable", "-n1", "-c1", "-o", str(slurm.root / "out-%j.txt"), str(path)],
                          capture_output=True, text=True, env=env, timeout=60, check=False)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.strip().split(";")[0]


def _assert_exact(record: dict[str, Any], stream: StreamRecorder) -> None:
    """Each segment's energy per DRAM channel is the integral of the streamed samples over its span."""
    for segment in record["segments"]:
        for channel, (first, last) in segment["samples_ns"].items():
            if channel.startswith("DDR"):
                expected = stream.integral(channel, first, last)
                assert segment["energy_j"][channel] == pytest.approx(expected, rel=1e-9, abs=1e-9), channel
    dram = [c for c in record["energy_j"] if c.startswith("DDR")]
    total = sum(s["energy_j"][c] for s in record["segments"] for c in dram)
    assert record["dram_energy_j"] == pytest.approx(total, rel=1e-12)


def test_an_sbatch_job_has_its_exact_dram_energy(slurm: Any, daemon: dict[str, Any]) -> None:
    """A batch job: the Prolog opened its window, `hdeem-watch jobs --job $SLURM_JOB_ID` inside the
    job shows its energy so far, dram-energy.sh prints it at the end of the job's output, the Epilog
    closed it; the stored record's energy per sensor equals the integral of the daemon's streamed
    samples over the job's window."""
    wrapper = Path(__file__).resolve().parents[2] / "daemon" / "slurm" / "dram-energy.sh"
    job_id = _sbatch(slurm, f"sleep 1.5\n{sys.executable} -m hdeem_watch jobs --job $SLURM_JOB_ID --json\n"
                            f"{wrapper} sleep 1\n")
    epilog = slurm.hook_records(job_id, "epilog", timeout=60)
    prolog = slurm.hook_records(job_id, "prolog")
    assert prolog["job_start"] == "ok" and epilog["job_stop"] == "ok" and epilog["state"] == "done"
    answer = _jobs_cli(slurm, "--job", job_id)["nodes"]
    assert len(answer) == 1 and answer[0]["ok"] and answer[0]["node"] == slurm.node
    record = answer[0]["jobs"][0]
    assert record["state"] == "done" and record["user"] == "root" and record["uid"] == 0
    assert record["nodes"] == [slurm.node] and record["exit_code"] == 0 and record["status"] == "ok"
    assert len(record["segments"]) == 1 and 2.0 < record["measured_s"] < 30
    _assert_exact(record, daemon["stream"])
    output = (slurm.root / f"out-{job_id}.txt").read_text()
    inside = json.loads(next(line for line in output.splitlines() if line.startswith("{")))
    so_far = inside["nodes"][0]["jobs"][0]
    assert so_far["state"] == "running" and 0 < so_far["dram_energy_j"] < record["dram_energy_j"]
    # dram-energy.sh ends with the job's table: its node's line, then its state under it
    lines = output.splitlines()
    row = max(i for i, line in enumerate(lines) if line.split()[:2] == [slurm.node, job_id])
    assert lines[row + 1].split()[0] == "running:", output
    listed = _jobs_cli(slurm, "--user", "root", "--since", "10min")["nodes"][0]["jobs"]
    assert job_id in [j["job_id"] for j in listed]


def test_a_job_keeps_its_energy_when_the_daemon_is_killed_mid_job(slurm: Any, daemon: dict[str, Any]) -> None:
    """kill -9 of the daemon during a job: the restarted daemon resumes the job; the Epilog's stop
    closes it; the record has both segments, each exact against the streamed samples, and the gap
    between them marked as unmeasured."""
    from hdeem_watch.wire.client import ControlClient, ControlError

    job_id = _sbatch(slurm, "sleep 7\n")
    deadline = time.monotonic() + 30
    with ControlClient(slurm.control, timeout_s=2.0) as client:
        while True:
            try:
                if client.call("job.get", {"job_id": job_id})["state"] == "running":
                    break
            except ControlError:
                pass
            assert time.monotonic() < deadline, "the Prolog never opened the job"
            time.sleep(0.1)
    time.sleep(3.0)  # checkpoints every second (job_checkpoint_s = 1 in the daemon's config)
    daemon["proc"].kill()
    daemon["proc"].wait(timeout=10)
    time.sleep(0.5)
    daemon["proc"] = slurm.start_daemon()
    epilog = slurm.hook_records(job_id, "epilog", timeout=60)
    assert epilog["job_stop"] == "ok", epilog
    record = _jobs_cli(slurm, "--job", job_id)["nodes"][0]["jobs"][0]
    assert record["state"] == "done" and len(record["segments"]) == 2, record["status"]
    assert record["status"].startswith("gap:") and 0.3 < record["unmeasured_s"] < 10
    assert record["segments"][0]["spans_s"]["DDR_AB"] >= 1.0
    _assert_exact(record, daemon["stream"])
