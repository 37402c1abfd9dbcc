"""Tests of the SLURM adapter: hostlists, CPUs of a task, and the bench under a real SLURM."""

from __future__ import annotations

import json
import sys

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hdeem_watch.errors import InputError
from hdeem_watch.slurm import (
    allocation_nodes,
    allowed_cpus,
    expand_hostlist,
    in_allocation,
    job_metadata,
)

#: The tests on the real SLURM run on one xdist worker with the other SLURM tests (one munged, one
#: cluster at a time); the hostlist tests beside them take no time there.
pytestmark = pytest.mark.xdist_group("slurm")

HOSTLISTS = {
    "node[01-03,07],other": ["node01", "node02", "node03", "node07", "other"],
    "n[8-11]": ["n8", "n9", "n10", "n11"],
    "n[098-101]": ["n098", "n099", "n100", "n101"],
    "taurusi[6001,6003-6004]": ["taurusi6001", "taurusi6003", "taurusi6004"],
    "r[1-2]n[1-2]": ["r1n1", "r1n2", "r2n1", "r2n2"],
    "a,b,a": ["a", "b"],
    "single": ["single"],
    "": [],
}


@pytest.mark.parametrize(("hostlist", "hosts"), list(HOSTLISTS.items()))
def test_expand_hostlist(hostlist: str, hosts: list[str]) -> None:
    """Hostlists expand in order with zero padding, lists, several groups, and no duplicates."""
    assert expand_hostlist(hostlist) == hosts


@pytest.mark.parametrize("bad", ["n[1-2", "n1-2]", "n[[1]]", "n[2-1]", "n[a-b]", "n[1-99999999]", "n[]"])
def test_expand_hostlist_rejects_malformed(bad: str) -> None:
    """Malformed hostlists raise a one-line InputError naming the hostlist."""
    with pytest.raises(InputError) as info:
        expand_hostlist(bad)
    assert "hostlist" in str(info.value) and "\n" not in str(info.value)


def test_allocation_from_environment() -> None:
    """The job's nodes come from SLURM_JOB_NODELIST (else SLURM_NODELIST); none outside a job."""
    assert allocation_nodes({"SLURM_JOB_NODELIST": "c[1-2]", "SLURM_NODELIST": "x"}) == ["c1", "c2"]
    assert allocation_nodes({"SLURM_NODELIST": "x[3]"}) == ["x3"]
    assert allocation_nodes({}) == []
    assert in_allocation({"SLURM_JOB_ID": "42"}) and not in_allocation({})
    assert job_metadata({}) == {}
    meta = job_metadata({"SLURM_JOB_ID": "42", "SLURM_STEP_ID": "0", "SLURM_JOB_NODELIST": "c1"})
    assert meta == {"slurm_job_id": "42", "slurm_step_id": "0", "slurm_nodelist": "c1"}


def test_allowed_cpus_follows_the_task_share() -> None:
    """Outside SLURM all CPUs of the mask; in a task SLURM_CPUS_PER_TASK cuts an unbound mask;
    a mask SLURM already narrowed is kept."""
    mask = {0, 1, 2, 3, 4, 5, 6, 7}
    assert allowed_cpus({}, mask) == list(range(8))
    assert allowed_cpus({"SLURM_JOB_ID": "1", "SLURM_CPUS_PER_TASK": "2"}, mask) == [0, 1]
    assert allowed_cpus({"SLURM_JOB_ID": "1", "SLURM_CPUS_ON_NODE": "3"}, mask) == [0, 1, 2]
    assert allowed_cpus({"SLURM_JOB_ID": "1", "SLURM_CPUS_PER_TASK": "4"}, {5, 6}) == [5, 6]
    assert allowed_cpus({"SLURM_CPUS_PER_TASK": "1"}, mask) == list(range(8))  # not in a job


# ------------------------------------------------------------------------------------ real SLURM
@pytest.mark.slow
@pytest.mark.slurm
def test_hostlist_matches_scontrol(slurm) -> None:  # type: ignore[no-untyped-def]
    """Our expander gives what SLURM's own `scontrol show hostnames` gives."""
    for hostlist, hosts in HOSTLISTS.items():
        if not hostlist:
            continue
        proc = slurm.run(["scontrol", "show", "hostnames", hostlist])
        assert proc.returncode == 0, proc.stderr
        ours = expand_hostlist(hostlist)
        theirs = proc.stdout.split()
        if hostlist == "a,b,a":  # scontrol keeps duplicates; we list each host once
            theirs = list(dict.fromkeys(theirs))
        assert ours == theirs == hosts


@pytest.mark.slow
@pytest.mark.slurm
def test_allocation_nodes_inside_a_real_allocation(slurm) -> None:  # type: ignore[no-untyped-def]
    """Inside srun, allocation_nodes() expands the real SLURM_JOB_NODELIST to this node."""
    code = ("import json, os; from hdeem_watch import slurm; "
            "print(json.dumps([slurm.allocation_nodes(), os.environ['SLURM_JOB_NODELIST'], "
            "slurm.in_allocation(), slurm.job_metadata()]))")
    proc = slurm.run(["srun", "-n1", "-c1", sys.executable, "-c", code])
    assert proc.returncode == 0, proc.stderr
    nodes, nodelist, inside, meta = json.loads(proc.stdout)
    assert nodes == [slurm.node] and nodelist == slurm.node and inside
    assert meta["slurm_nodelist"] == slurm.node and meta["slurm_job_id"].isdigit()


@pytest.mark.slow
@pytest.mark.slurm
def test_bench_under_srun_respects_given_cpus(slurm) -> None:  # type: ignore[no-untyped-def]
    """`srun -n1 -c1 hdeem-watch bench` runs its worker on the one CPU SLURM bound the task to and
    refuses a second thread; with -c2 it uses two distinct CPUs of the task's mask."""
    bench = f"{sys.executable} -m hdeem_watch bench --kernels copy --elements 65536 --repeat 2 --json"
    mask = f"{sys.executable} -c 'import os; print(sorted(os.sched_getaffinity(0)))'"
    proc = slurm.run(["srun", "-n1", "-c1", "sh", "-c", f"{mask} && {bench} --threads 1"])
    assert proc.returncode == 0, proc.stderr
    mask_line, record_line = proc.stdout.splitlines()
    task_cpus = json.loads(mask_line)
    record = json.loads(record_line)
    assert len(task_cpus) == 1  # task/affinity bound the task to one CPU
    assert record["threads"] == 1 and record["cpus"] == task_cpus and record["seconds"] > 0
    proc = slurm.run(["srun", "-n1", "-c1", "sh", "-c", f"{bench} --threads 2"])
    assert proc.returncode == 2
    assert "only 1 CPUs" in proc.stderr
    if slurm.cpus >= 2:
        proc = slurm.run(["srun", "-n1", "-c2", "sh", "-c", f"{mask} && {bench} --threads 2"])
        assert proc.returncode == 0, proc.stderr
        mask_line, record_line = proc.stdout.splitlines()
        cpus = json.loads(record_line)["cpus"]
        assert len(set(cpus)) == 2 and set(cpus) <= set(json.loads(mask_line))


@pytest.mark.slow
@pytest.mark.slurm
def test_bench_under_unbound_srun_uses_its_cpu_share(slurm) -> None:  # type: ignore[no-untyped-def]
    """When the task's mask is the whole node (no binding, as under TaskPlugin=task/none; here
    the task widens its own mask with taskset), the bench still limits itself to the -c1 share
    SLURM gave it (SLURM_CPUS_PER_TASK from the real srun)."""
    widen = ["taskset", "-c", f"0-{slurm.cpus - 1}"]
    code = ("import json, os; from hdeem_watch import slurm; "
            "print(json.dumps([sorted(os.sched_getaffinity(0)), slurm.allowed_cpus()]))")
    proc = slurm.run(["srun", "-n1", "-c1", *widen, sys.executable, "-c", code])
    assert proc.returncode == 0, proc.stderr
    mask, allowed = json.loads(proc.stdout)
    assert len(mask) == slurm.cpus and len(allowed) == 1 and set(allowed) <= set(mask)
    proc = slurm.run(["srun", "-n1", "-c1", *widen, sys.executable, "-m", "hdeem_watch", "bench",
                      "--kernels", "read", "--threads", "2", "--elements", "8192", "--json"])
    assert proc.returncode == 2 and "only 1 CPUs" in proc.stderr


@pytest.mark.slow
@pytest.mark.slurm
def test_hooks_without_a_daemon_record_the_job_and_leave_nothing_behind(slurm) -> None:  # type: ignore[no-untyped-def]
    """No daemon runs: the Prolog says so (and does not start one: not asked to), the Epilog sends no
    stop for a job that was not started, both exit 0 (the job runs), and the per-job file is gone."""
    proc = slurm.run(["srun", "-n1", "-c1", "sh", "-c", "echo $SLURM_JOB_ID"])
    assert proc.returncode == 0, proc.stderr
    job_id = proc.stdout.strip()
    prolog = slurm.hook_records(job_id, "prolog")
    epilog = slurm.hook_records(job_id, "epilog")
    assert job_id.isdigit() and prolog["node"] == slurm.node and prolog["user"] == "root"
    assert prolog["daemon"] == "none" and epilog["job_stop"] == "skipped: not started"
    assert int(prolog["t_ns"]) <= int(epilog["t_ns"])  # type: ignore[call-overload]
    assert epilog["exit_code"] is not None and not (slurm.hook_dir / f"job-{job_id}.json").exists()
    assert not list(slurm.hook_dir.glob("stop-*.json")) and oct(slurm.hook_dir.stat().st_mode & 0o777) == "0o700"


@pytest.mark.slow
@pytest.mark.slurm
def test_prolog_starts_a_daemon_only_when_asked_and_the_last_epilog_stops_it(slurm) -> None:  # type: ignore[no-untyped-def]
    """With HDEEM_WATCH_START_DAEMON=1 the Prolog starts a daemon from the daemon's own config file,
    opens the job there, the bench in the job announces its run to it, and the Epilog closes the job
    and stops the daemon (no job left on it)."""
    slurm.hook_conf.write_text("HDEEM_WATCH_START_DAEMON=1\n")
    try:
        proc = slurm.run(["srun", "-n1", "-c1", sys.executable, "-m", "hdeem_watch", "bench", "--kernels", "copy",
                          "--threads", "1", "--elements", "65536", "--repeat", "2", "--daemon", slurm.control, "--json"],
                         timeout=120)
        assert proc.returncode == 0, proc.stderr
        record = json.loads(proc.stdout)
        assert record["run_id"] and record["daemon"]["kernel"] == "copy"
        job_id = record["daemon"]["metadata"]["slurm_job_id"]
        prolog = slurm.hook_records(job_id, "prolog")
        epilog = slurm.hook_records(job_id, "epilog")
        assert prolog["daemon"] == "started" and prolog["job_start"] == "ok"
        assert epilog["job_stop"] == "ok" and epilog["state"] == "done" and epilog["daemon"] == "stopped"
        assert not (slurm.hook_dir / "daemon.json").exists()
        from hdeem_watch.wire.client import ControlClient, DaemonUnreachable

        with ControlClient(slurm.control, timeout_s=0.5) as client, pytest.raises(DaemonUnreachable):
            client.call("ping")
    finally:
        slurm.hook_conf.unlink(missing_ok=True)


@given(st.lists(st.tuples(st.sampled_from(["n", "node", "rack-", "x1y"]),
                          st.lists(st.tuples(st.integers(0, 300), st.integers(0, 20), st.integers(1, 4)),
                                   min_size=1, max_size=4)), min_size=1, max_size=3))
def test_expand_hostlist_property(items: list[tuple[str, list[tuple[int, int, int]]]]) -> None:
    """Any comma list of prefix[lo-hi,...] groups expands to the zero-padded names in order."""
    parts, expected = [], []
    for prefix, ranges in items:
        body = []
        for lo, span, width in ranges:
            hi = lo + span
            body.append(f"{lo:0{width}d}-{hi:0{width}d}" if span else f"{lo:0{width}d}")
            expected.extend(f"{prefix}{n:0{width}d}" for n in range(lo, hi + 1))
        parts.append(f"{prefix}[{','.join(body)}]")
    assert expand_hostlist(",".join(parts)) == list(dict.fromkeys(expected))
