"""The one module that reads SLURM's environment.

Everything else asks this adapter: which nodes the job has (:func:`allocation_nodes`, with a pure
expander of SLURM hostlists such as ``node[01-03,07],other``), which CPUs this task may use
(:func:`allowed_cpus`), whether we run inside an allocation (:func:`in_allocation`) and what to
record about the job (:func:`job_metadata`). The SLURM Prolog/Epilog hooks in ``daemon/slurm/``
run ``python3 -m hdeem_watch.slurm prolog|epilog`` (:mod:`hdeem_watch.slurm.hooks`; docs/slurm.md).

Example:
    >>> expand_hostlist("node[01-03,07],login")
    ['node01', 'node02', 'node03', 'node07', 'login']
    >>> allocation_nodes({"SLURM_JOB_NODELIST": "c[1-2]"})
    ['c1', 'c2']
"""

from __future__ import annotations

import itertools
import os
import re
from collections.abc import Mapping

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
