"""A job spanning two nodes of a real SLURM, watched allocation-wide over CURVE TCP.

The cluster (two slurmd on this machine, one sim daemon per node on the one documented control
port) is the ``two_node_cluster`` fixture of ``conftest.py``. The job runs a task on each node and, from inside the
allocation, the TUI with ``--slurm`` (headless), which finds both daemons by node name, asks each
for its status over CURVE-encrypted TCP, subscribes to the TCP stream each advertises and prints
both nodes' power; without the server's key the same command stops at once with the reason.
The Prolog opened the job's window on both nodes, so ``hdeem-watch jobs`` reports the job's DRAM
energy from both — from inside the job (this node by ipc, the other over CURVE TCP) and, after the
Epilog closed the windows, from the "login node" over TCP alone.
"""

from __future__ import annotations

import json
import sys
import time
from typing import Any

import pytest

#: A real SLURM: slow, and on one xdist worker with the other SLURM tests (one munged, one
#: cluster at a time).
pytestmark = [pytest.mark.slurm, pytest.mark.slow, pytest.mark.xdist_group("slurm")]


def _job(cluster: Any, script: str, timeout: float = 60) -> str:
    """Submit ``script`` on both nodes, wait for it, return its output."""
    output = cluster.root / f"job-{time.monotonic_ns()}.out"
    path = output.with_suffix(".sh")
    path.write_text("#!/bin/sh\n" + script)
    path.chmod(0o755)
    submitted = cluster.run(["sbatch", "--parsable", "-N2", "-n2", f"--output={output}", str(path)])
    assert submitted.returncode == 0, submitted.stderr
    job_id = submitted.stdout.strip().split(";")[0]
    cluster.wait_for_job(job_id, timeout)
    return output.read_text()


def test_the_tui_watches_both_nodes_of_a_job_over_curve_tcp(two_node_cluster: Any) -> None:
    cluster = two_node_cluster
    nodes = sorted(cluster.daemons)  # hwn1, hwn2
    tui = (f"HDEEM_WATCH_CONFIG=/nonexistent {sys.executable} -m hdeem_watch tui --slurm --port {cluster.control_port} "
           "--headless --duration 4")
    keys = f"--server-key {cluster.server_key} --client-key {cluster.client_key}"
    started = time.monotonic()
    out = _job(cluster, "\n".join([
        "srun -N2 -n2 sh -c 'echo task on $SLURMD_NODENAME'",
        cluster.login_command(f"{tui} {keys} 2>&1; echo tui exit $?"),
        cluster.login_command(f"{tui} 2>&1; echo tui exit $?"),
        ""]))
    assert time.monotonic() - started < 45
    lines = out.splitlines()
    assert sorted(line for line in lines if line.startswith("task on")) == [f"task on {n}" for n in nodes], out
    with_keys, without = out.split("tui exit", 1)
    exits = [line for line in lines if line.startswith("tui exit")]
    assert exits == ["tui exit 0", "tui exit 2"], out
    for node in nodes:
        assert f"state  {node} live" in with_keys, out
        assert any(line.startswith(f"[{node}] power  DDR_AB") for line in with_keys.splitlines()), out
    refusal = [line for line in without.splitlines() if line.startswith("hdeem-watch: error:")]
    assert len(refusal) == 1 and "the daemon requires CURVE: give its public key" in refusal[0], out


def _jobs_answer(text: str) -> dict[str, dict[str, object]]:
    """``jobs --json`` output → ``{node: answer}``."""
    line = next(line for line in text.splitlines() if line.startswith("{"))
    return {answer["node"]: answer for answer in json.loads(line)["nodes"]}


def test_jobs_reports_the_energy_of_a_two_node_job_from_both_nodes(two_node_cluster: Any) -> None:
    cluster = two_node_cluster
    nodes = sorted(cluster.daemons)  # hwn1, hwn2
    keys = f"HDEEM_WATCH_SERVER_KEY={cluster.server_key} HDEEM_WATCH_CLIENT_KEY={cluster.client_key}"
    jobs = (f'{keys} HDEEM_WATCH_CONFIG="{cluster.root}/$SLURMD_NODENAME/hdeem-watchd.toml" {sys.executable} '
            f"-m hdeem_watch jobs --port {cluster.control_port} --json")
    out = _job(cluster, "\n".join([
        "srun -N2 -n2 sleep 2",
        cluster.login_command(f"{jobs} --job $SLURM_JOB_ID 2>&1; echo jobs exit $?"),
        "echo job id $SLURM_JOB_ID",
        ""]))
    assert "jobs exit 0" in out, out
    job_id = next(line.split()[-1] for line in out.splitlines() if line.startswith("job id"))
    inside = _jobs_answer(out)
    assert sorted(inside) == nodes, out
    for answer in inside.values():
        assert answer["ok"], answer
        (record,) = answer["jobs"]  # type: ignore[misc]
        assert record["job_id"] == job_id and record["state"] == "running" and record["dram_energy_j"] > 0, record
    assert inside["hwn1"]["endpoint"].startswith("ipc://") and inside["hwn2"]["endpoint"].startswith("tcp://hwn2:")

    # After the Epilog, from the login node: both nodes over CURVE TCP, the finished records.
    login = cluster.run(["sh", "-c", cluster.login_command(
        f"{keys} HDEEM_WATCH_CONFIG=/nonexistent {sys.executable} -m hdeem_watch jobs --port {cluster.control_port} "
        + "".join(f" --connect tcp://{node}:{cluster.control_port}" for node in nodes) + f" --job {job_id} --json")])
    assert login.returncode == 0, login.stdout + login.stderr
    after = _jobs_answer(login.stdout)
    for node in nodes:
        (record,) = after[node]["jobs"]  # type: ignore[misc]
        assert after[node]["endpoint"].startswith(f"tcp://{node}:")
        assert record["state"] == "done" and record["dram_energy_j"] > 0 and record["nodes"], record
