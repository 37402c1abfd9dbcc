"""The one module that reads SLURM's environment.

Everything else asks this adapter: which nodes the job has (:func:`allocation_nodes`, with a pure
expander of SLURM hostlists such as ``node[01-03,07],other``), which CPUs this task may use
(:func:`allowed_cpus`), whether we run inside an allocation (:func:`in_allocation`) and what to
record about the job (:func:`job_metadata`). The SLURM Prolog/Epilog hooks in ``daemon/slurm/``
call :func:`main` (``python3 -m hdeem_watch.slurm prolog|epilog``): see :func:`prolog` and
:func:`epilog` and docs/bench.md.

Example:
    >>> expand_hostlist("node[01-03,07],login")
    ['node01', 'node02', 'node03', 'node07', 'login']
    >>> allocation_nodes({"SLURM_JOB_NODELIST": "c[1-2]"})
    ['c1', 'c2']
"""

from __future__ import annotations

import contextlib
import itertools
import json
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from hdeem_watch.errors import InputError

#: Most hosts one hostlist may expand to (a typo such as ``n[1-99999999]`` must not eat memory).
MAX_HOSTS = 1_000_000

_RANGE = re.compile(r"^(\d+)(?:-(\d+))?$")


def _split_top(text: str) -> list[str]:
    """Split on commas that are not inside brackets."""
    items, depth, start = [], 0, 0
    for i, ch in enumerate(text):
        if ch == "[":
            depth += 1
            if depth > 1:
                raise InputError(f"hostlist {text!r}: nested '[' at {i}; expected name[01-03,07]")
        elif ch == "]":
            depth -= 1
            if depth < 0:
                raise InputError(f"hostlist {text!r}: unmatched ']' at {i}; expected name[01-03,07]")
        elif ch == "," and depth == 0:
            items.append(text[start:i])
            start = i + 1
    if depth != 0:
        raise InputError(f"hostlist {text!r}: unclosed '['; expected name[01-03,07]")
    items.append(text[start:])
    return items


def _expand_range(body: str, whole: str) -> list[str]:
    out: list[str] = []
    for part in body.split(","):
        match = _RANGE.match(part.strip())
        if not match:
            raise InputError(f"hostlist {whole!r}: bad range {part!r}; expected N or N-M inside [...]")
        lo_text, hi_text = match.group(1), match.group(2)
        lo = int(lo_text)
        hi = lo if hi_text is None else int(hi_text)
        if hi < lo:
            raise InputError(f"hostlist {whole!r}: descending range {part!r}; expected N-M with N <= M")
        if hi - lo + 1 > MAX_HOSTS:
            raise InputError(f"hostlist {whole!r}: range {part!r} is too large (> {MAX_HOSTS} hosts)")
        width = len(lo_text)
        out.extend(str(n).zfill(width) for n in range(lo, hi + 1))
    return out


def expand_hostlist(hostlist: str) -> list[str]:
    """Expand a SLURM hostlist expression into host names, in order, without duplicates.

    Supports comma-separated items, bracketed ranges with zero padding (``n[001-010]``), lists in
    brackets (``n[1,3,5-7]``) and several bracket groups in one name (``r[1-2]n[1-2]`` →
    r1n1 r1n2 r2n1 r2n2), as ``scontrol show hostnames`` does.

    Raises:
        InputError: unbalanced brackets, bad or descending ranges, or an absurd size.
    """
    hosts: list[str] = []
    seen: set[str] = set()
    text = hostlist.strip()
    if not text:
        return []
    for item in _split_top(text):
        item = item.strip()
        if not item:
            continue
        pieces: list[list[str]] = []
        pos = 0
        for match in re.finditer(r"\[([^\]]*)\]", item):
            pieces.append([item[pos:match.start()]])
            pieces.append(_expand_range(match.group(1), hostlist))
            pos = match.end()
        pieces.append([item[pos:]])
        if any(ch in "[]" for piece in pieces if len(piece) == 1 for ch in piece[0]):
            raise InputError(f"hostlist {hostlist!r}: stray bracket in {item!r}")
        for combo in itertools.product(*pieces):
            name = "".join(combo)
            if name not in seen:
                seen.add(name)
                hosts.append(name)
                if len(hosts) > MAX_HOSTS:
                    raise InputError(f"hostlist {hostlist!r}: more than {MAX_HOSTS} hosts")
    return hosts


def in_allocation(env: Mapping[str, str] | None = None) -> bool:
    """Return True inside a SLURM job (``SLURM_JOB_ID`` set)."""
    env = os.environ if env is None else env
    return bool(env.get("SLURM_JOB_ID") or env.get("SLURM_JOBID"))


def allocation_nodes(env: Mapping[str, str] | None = None) -> list[str]:
    """Return the job's nodes, expanded from ``SLURM_JOB_NODELIST`` (or ``SLURM_NODELIST``).

    Returns an empty list outside an allocation.
    """
    env = os.environ if env is None else env
    nodelist = env.get("SLURM_JOB_NODELIST") or env.get("SLURM_NODELIST") or ""
    return expand_hostlist(nodelist)


def _cpu_count(env: Mapping[str, str]) -> int | None:
    """CPUs SLURM gave this task: ``SLURM_CPUS_PER_TASK`` in a step, else ``SLURM_CPUS_ON_NODE``."""
    for key in ("SLURM_CPUS_PER_TASK", "SLURM_CPUS_ON_NODE"):
        value = env.get(key, "").strip()
        if value.isdigit() and int(value) > 0:
            return int(value)
    return None


def allowed_cpus(env: Mapping[str, str] | None = None, affinity: set[int] | None = None) -> list[int]:
    """Return the CPUs this process may use, sorted.

    Outside SLURM this is the affinity mask (``os.sched_getaffinity(0)``: ``taskset``, cpusets).
    Inside an allocation SLURM's binding (task/affinity, cgroups) already narrows the mask; when it
    does not (``TaskPlugin=task/none``), the mask is cut to the number of CPUs SLURM gave the task
    (``SLURM_CPUS_PER_TASK``, else ``SLURM_CPUS_ON_NODE``), lowest numbers first.

    Args:
        env: environment (default ``os.environ``).
        affinity: the affinity mask (default this process's).
    """
    env = os.environ if env is None else env
    cpus = sorted(os.sched_getaffinity(0) if affinity is None else affinity)
    if in_allocation(env):
        count = _cpu_count(env)
        if count is not None and count < len(cpus):
            cpus = cpus[:count]
    return cpus


def job_metadata(env: Mapping[str, str] | None = None) -> dict[str, str]:
    """Return what identifies the job and step, for run announcements (empty outside SLURM)."""
    env = os.environ if env is None else env
    if not in_allocation(env):
        return {}
    keys = {"slurm_job_id": ("SLURM_JOB_ID", "SLURM_JOBID"), "slurm_step_id": ("SLURM_STEP_ID",),
            "slurm_job_user": ("SLURM_JOB_USER",), "slurm_nodelist": ("SLURM_JOB_NODELIST", "SLURM_NODELIST"),
            "slurm_cluster": ("SLURM_CLUSTER_NAME",), "slurm_node": ("SLURMD_NODENAME",)}
    out: dict[str, str] = {}
    for name, candidates in keys.items():
        for key in candidates:
            if env.get(key):
                out[name] = env[key]
                break
    return out


def hook_context(env: Mapping[str, str] | None = None) -> dict[str, str]:
    """Return the job fields a Prolog/Epilog sees (job id, user, uid, nodes, exit code)."""
    env = os.environ if env is None else env
    fields = {"job_id": "SLURM_JOB_ID", "user": "SLURM_JOB_USER", "uid": "SLURM_JOB_UID",
              "nodelist": "SLURM_NODELIST", "node": "SLURMD_NODENAME", "context": "SLURM_SCRIPT_CONTEXT",
              "exit_code": "SLURM_JOB_EXIT_CODE", "partition": "SLURM_JOB_PARTITION"}
    return {name: env[key] for name, key in fields.items() if env.get(key)}


def hook_setting(name: str, default: str, env: Mapping[str, str] | None = None) -> str:
    """Return a hook setting ``HDEEM_WATCH_<NAME>`` from the environment (or ``default``)."""
    env = os.environ if env is None else env
    return env.get(f"HDEEM_WATCH_{name.upper()}", default)



# --------------------------------------------------------------------------- Prolog / Epilog hooks
#: Default directory of the hooks' per-job records and their job log.
DEFAULT_HOOK_DIR = "/run/hdeem-watch/slurm"


def _hook_dir(env: Mapping[str, str]) -> Path:
    return Path(hook_setting("hook_dir", DEFAULT_HOOK_DIR, env))


def _control_endpoint(env: Mapping[str, str]) -> tuple[str, str]:
    from hdeem_watch.daemon.client import default_endpoints

    pub, control = default_endpoints(env.get("HDEEM_WATCH_RUNTIME_DIR") or None)
    return hook_setting("pub", pub, env), hook_setting("control", control, env)


def _daemon_status(control: str, timeout_s: float) -> dict[str, Any] | None:
    from hdeem_watch.daemon.client import ControlClient, ControlError, DaemonUnreachable

    with ControlClient(control, timeout_s=timeout_s) as client:
        try:
            result = client.call("status")
        except (DaemonUnreachable, ControlError):
            return None
    return result if isinstance(result, dict) else {}


def _log(message: str) -> None:
    print(f"hdeem-watch slurm hook: {message}", file=sys.stderr)


def prolog(env: Mapping[str, str] | None = None) -> dict[str, Any]:
    """Prolog: make sure a daemon watches this node for the job and record the job's start.

    If a daemon answers on the control endpoint it is used (``daemon: "running"``); optionally a
    quiet baseline is measured first (``HDEEM_WATCH_PROLOG_BASELINE_S`` > 0, ``baseline.measure``).
    Otherwise, if ``HDEEM_WATCH_START_DAEMON=1``, a daemon is started for the job
    (``hdeem-watch daemon --source $HDEEM_WATCH_SOURCE --pub ... --control ... --state-dir ...``,
    detached, waited for until it answers) and the Epilog stops it (``daemon: "started"``). The
    record ``job-<id>.json`` goes to ``$HDEEM_WATCH_HOOK_DIR`` (default /run/hdeem-watch/slurm).

    Returns:
        The job record written.
    """
    env = os.environ if env is None else env
    ctx = hook_context(env)
    job_id = ctx.get("job_id", "unknown")
    pub, control = _control_endpoint(env)
    hook_dir = _hook_dir(env)
    hook_dir.mkdir(parents=True, exist_ok=True)
    record: dict[str, Any] = {**ctx, "nodes": allocation_nodes({"SLURM_NODELIST": ctx.get("nodelist", "")}),
                              "t_start_ns": time.time_ns(), "control": control, "pub": pub,
                              "daemon": "none", "pid": None}
    if _daemon_status(control, 1.0) is not None:
        record["daemon"] = "running"
        baseline_s = float(hook_setting("prolog_baseline_s", "0", env) or 0)
        if baseline_s > 0:
            from hdeem_watch.daemon.client import ControlClient, ControlError, DaemonUnreachable

            with ControlClient(control, timeout_s=baseline_s + 5.0) as client:
                try:
                    client.call("baseline.measure", {"seconds": baseline_s})
                    record["baseline_s"] = baseline_s
                except (DaemonUnreachable, ControlError) as error:
                    _log(f"job {job_id}: baseline.measure failed: {error}")
    elif hook_setting("start_daemon", "0", env) == "1":
        state_dir = Path(hook_setting("state_dir", str(hook_dir / f"state-{job_id}"), env))
        state_dir.mkdir(parents=True, exist_ok=True)
        command = [sys.executable, "-m", "hdeem_watch", "daemon", "--source",
                   hook_setting("source", "sim", env), "--pub", pub, "--control", control,
                   "--state-dir", str(state_dir), *hook_setting("daemon_args", "", env).split()]
        with open(hook_dir / f"daemon-{job_id}.log", "ab") as log:
            proc = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=log, stderr=log,
                                    start_new_session=True, close_fds=True)
        record.update(daemon="started", pid=proc.pid, command=command)
        deadline = time.monotonic() + float(hook_setting("start_timeout_s", "20", env))
        while time.monotonic() < deadline and proc.poll() is None:
            if _daemon_status(control, 0.5) is not None:
                break
            time.sleep(0.1)
        else:
            _log(f"job {job_id}: the daemon started for the job did not answer on {control}")
    (hook_dir / f"job-{job_id}.json").write_text(json.dumps(record))
    return record


def _stop_pid(pid: int, timeout_s: float = 10.0) -> None:
    try:
        os.kill(pid, signal.SIGTERM)
    except ProcessLookupError:
        return
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            finished, _ = os.waitpid(pid, os.WNOHANG)
            if finished == pid:
                return
        except ChildProcessError:  # not our child (started by another hook process)
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                return
        time.sleep(0.05)
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, signal.SIGKILL)


def epilog(env: Mapping[str, str] | None = None) -> dict[str, Any]:
    """Epilog: record the job's end in ``jobs.jsonl`` and stop the daemon the Prolog started.

    Returns:
        The finished job record (``t_end_ns`` and ``exit_code`` added).
    """
    env = os.environ if env is None else env
    ctx = hook_context(env)
    job_id = ctx.get("job_id", "unknown")
    hook_dir = _hook_dir(env)
    path = hook_dir / f"job-{job_id}.json"
    try:
        record: dict[str, Any] = json.loads(path.read_text())
    except (OSError, ValueError):
        record = {**ctx, "daemon": "none", "pid": None}
    record["t_end_ns"] = time.time_ns()
    record["exit_code"] = ctx.get("exit_code")
    if record.get("daemon") == "started" and record.get("pid"):
        _stop_pid(int(record["pid"]))
        record["daemon"] = "stopped"
    hook_dir.mkdir(parents=True, exist_ok=True)
    with open(hook_dir / "jobs.jsonl", "a") as log:
        log.write(json.dumps(record) + "\n")
    path.unlink(missing_ok=True)
    return record


def main(argv: Sequence[str] | None = None) -> int:
    """Entry of the hooks: ``python3 -m hdeem_watch.slurm prolog|epilog|nodes``.

    The hooks always exit 0 (a failing Prolog drains the node); failures go to stderr, which
    slurmd logs.
    """
    args = list(sys.argv[1:] if argv is None else argv)
    action = args[0] if args else ""
    if action == "nodes":
        print("\n".join(allocation_nodes()))
        return 0
    if action not in ("prolog", "epilog"):
        print("usage: python3 -m hdeem_watch.slurm prolog|epilog|nodes", file=sys.stderr)
        return 2
    try:
        record = prolog() if action == "prolog" else epilog()
        _log(f"{action} job {record.get('job_id')}: daemon {record.get('daemon')}")
    except Exception as error:  # never fail the hook
        _log(f"{action} failed: {type(error).__name__}: {error}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
