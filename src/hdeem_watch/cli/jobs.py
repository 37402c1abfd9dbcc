"""``hdeem-watch jobs``: SLURM jobs' DRAM energy from the node daemons.

On a node it asks the local daemon (``job.list``, or ``job.get`` with ``--job``); inside an
allocation, or with ``--slurm``, it asks the daemon of every node of the allocation at
``tcp://<node>:<port>`` (this node through its local endpoint), all at once, each with a bounded
timeout: a node that does not answer is a line saying so, not a hang. ``--connect EP`` names daemons
explicitly. From inside a job, ``hdeem-watch jobs --job $SLURM_JOB_ID`` prints the job's DRAM energy
so far on every node, and (with a counter source on the daemons) its modelled DRAM energy by
component.

Exit codes: 0 every node answered, 1 some node did not answer (or refused), 2 bad input.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import socket
import sys
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from hdeem_watch.cli.control_port import CONTROL_PORT, CONTROL_PORT_ENV, control_port
from hdeem_watch.cli.curve_options import add_server_key_argument, client_kwargs, curve_keys
from hdeem_watch.errors import InputError
from hdeem_watch.job_record import JobRecord
from hdeem_watch.report.records import is_dram_channel

_AGO = re.compile(r"^(\d+(?:\.\d+)?)\s*(s|min|h|d)$")
_UNITS = {"s": 1, "min": 60, "h": 3600, "d": 86400}


def register(subparsers: Any) -> None:
    """Add the ``jobs`` subcommand."""
    parser = subparsers.add_parser(
        "jobs", help="SLURM jobs' DRAM energy, per node (from the node daemons)",
        description="SLURM jobs' DRAM energy per node, as the node daemons measured it (running jobs: so far).",
        epilog="examples:\n"
        "  hdeem-watch jobs                          # this node's recent jobs\n"
        "  hdeem-watch jobs --job $SLURM_JOB_ID      # inside a job: its DRAM energy so far on every node\n"
        "  hdeem-watch jobs --user alice --since 2h --json\n"
        "  hdeem-watch jobs --slurm --job 4242       # from the login node, inside an salloc\n"
        "  hdeem-watch jobs --nodes 'n[01-04]' --job 4242   # a finished job's nodes, from anywhere\n"
        "exit codes: 0 every node answered, 1 a node did not answer, 2 bad input",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--job", metavar="ID", help="one job (its newest record on each node)")
    parser.add_argument("--user", metavar="U", help="only this user's jobs")
    parser.add_argument("--since", metavar="T", help="jobs running at or after T: 2h, 30min, 1d ago, or an ISO time")
    parser.add_argument("--limit", type=int, default=20, help="jobs per node (default 20)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--slurm", action="store_true",
                        help="ask every node of the allocation (default inside an allocation)")
    parser.add_argument("--nodes", metavar="HOSTLIST", help="ask these nodes (a SLURM hostlist, e.g. n[01-04]), "
                        "e.g. a finished job's")
    parser.add_argument("--connect", metavar="EP", action="append", default=[],
                        help="a daemon's control endpoint (repeatable); default: this node's daemon")
    parser.add_argument("--port", type=int, default=None,
                        help=f"control port of the daemons for --slurm (default ${CONTROL_PORT_ENV} or {CONTROL_PORT})")
    parser.add_argument("--timeout", type=float, default=3.0, metavar="S", help="per-node reply timeout (default 3)")
    add_server_key_argument(parser)
    parser.set_defaults(func=_run)


def parse_since(text: str, now_ns: int | None = None) -> int:
    """``--since``: ``<n>s|min|h|d`` ago, or an ISO 8601 time (local time when naive) → wall ns.

    >>> parse_since("2h", now_ns=10 * 3600 * 10**9) // 10**9
    28800

    Raises:
        InputError: neither form.
    """
    now_ns = time.time_ns() if now_ns is None else now_ns
    match = _AGO.match(text.strip())
    if match:
        return now_ns - round(float(match.group(1)) * _UNITS[match.group(2)] * 1e9)
    try:
        moment = datetime.fromisoformat(text.strip())
    except ValueError:
        raise InputError(f"--since {text!r}: expected a time ago (30min, 2h, 1d) or an ISO time "
                         "(2026-11-25T14:00)") from None
    return round(moment.timestamp() * 1e9)


@dataclass(frozen=True)
class Target:
    """One daemon to ask: its node name (as far as known) and control endpoint."""

    node: str
    endpoint: str


def targets(args: argparse.Namespace, env: Mapping[str, str] | None = None) -> list[Target]:
    """The daemons to ask (see the module docstring).

    Raises:
        InputError: ``--slurm`` outside an allocation, a bad port, a bad endpoint.
    """
    from hdeem_watch import slurm
    from hdeem_watch.slurm.hooks import local_control_endpoint

    env = os.environ if env is None else env
    found = []
    for endpoint in args.connect:
        if not endpoint.startswith(("ipc://", "tcp://", "inproc://")):
            raise InputError(f"--connect {endpoint!r}: expected a ZeroMQ endpoint such as tcp://node7:{CONTROL_PORT}")
        found.append(Target(endpoint.rpartition("/")[2], endpoint))
    given = getattr(args, "nodes", None)
    if given:
        nodes = slurm.expand_hostlist(given)
    else:
        nodes = slurm.allocation_nodes(env) if (args.slurm or not args.connect) else []
    if args.slurm and not nodes:
        raise InputError("--slurm: no SLURM allocation here (SLURM_JOB_NODELIST is not set); use --connect")
    if nodes:
        port = control_port(args.port, env)
        here = {env.get("SLURMD_NODENAME", ""), socket.gethostname().split(".")[0], socket.gethostname()}
        for node in nodes:
            endpoint = local_control_endpoint(env) if node in here else f"tcp://{node}:{port}"
            found.append(Target(node, endpoint))
    elif not found:
        found.append(Target(socket.gethostname().split(".")[0], local_control_endpoint(env)))
    return found


def ask(target: Target, op: str, request: dict[str, Any], *, timeout_s: float,
        keys: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """One daemon's answer: ``{"node", "endpoint", "ok": True, "jobs": [...]}`` or ``"ok": False``
    with ``"error"``; never raises for a daemon that is down or refuses. ``keys`` are the CURVE
    keyword arguments of the control client (:func:`hdeem_watch.cli.curve_options.client_kwargs`;
    without them the client takes the keys the environment names)."""
    from hdeem_watch.wire.client import ControlClient, ControlError, DaemonUnreachable

    entry: dict[str, Any] = {"node": target.node, "endpoint": target.endpoint}
    if (problem := unknown_host(target.endpoint)) is not None:
        return {**entry, "ok": False, "error": problem}
    try:
        with ControlClient(target.endpoint, timeout_s=timeout_s, **(keys or {})) as client:
            result = client.call(op, request)
    except DaemonUnreachable as error:
        return {**entry, "ok": False, "error": f"unreachable: {error}"}
    except ControlError as error:
        if error.code == "not-found":
            return {**entry, "ok": True, "jobs": []}
        return {**entry, "ok": False, "error": str(error)}
    jobs = result.get("jobs", []) if op == "job.list" else [result]
    return {**entry, "node": (jobs[0].get("node") if jobs else None) or target.node, "ok": True, "jobs": jobs}


def query(found: Sequence[Target], op: str, request: dict[str, Any], *, timeout_s: float,
          keys: Mapping[str, Any] | None = None) -> list[dict[str, Any]]:
    """Every daemon's answer, asked in parallel (the whole query takes about one timeout at most).

    The askers are daemon threads, so Ctrl-C ends the command at once (a pool would be waited for
    at exit: up to one timeout after the key)."""
    answers: list[dict[str, Any] | None] = [None] * len(found)

    def one(i: int, target: Target) -> None:
        answers[i] = ask(target, op, request, timeout_s=timeout_s, keys=keys)

    threads = [threading.Thread(target=one, args=(i, t), daemon=True, name=f"jobs-{t.node}")
               for i, t in enumerate(found)]
    for thread in threads:
        thread.start()
    for thread in threads:
        while thread.is_alive():
            thread.join(0.1)  # short waits: the main thread takes Ctrl-C between them
    return [a if a is not None else {"node": t.node, "endpoint": t.endpoint, "ok": False, "error": "no answer"}
            for a, t in zip(answers, found)]


def unknown_host(endpoint: str) -> str | None:
    """Why a ``tcp://HOST:PORT`` endpoint's host cannot be reached by name (None: it resolves, or
    another transport). ZeroMQ would only say "no reply" after the timeout.

    Example:
        >>> unknown_host("tcp://127.0.0.1:5591") is None, unknown_host("ipc:///run/x.sock") is None
        (True, True)
    """
    if not endpoint.startswith("tcp://"):
        return None
    host = endpoint[len("tcp://"):].rpartition(":")[0].strip("[]")
    if host in ("", "*"):
        return None
    try:
        socket.getaddrinfo(host, None)
    except (socket.gaierror, UnicodeError) as error:
        return f"unknown host {host!r} ({getattr(error, 'strerror', None) or error})"
    return None


def _fmt(value: Any, digits: int = 1) -> str:
    return "–" if not isinstance(value, int | float) or not math.isfinite(value) else f"{value:.{digits}f}"


def _count(value: Any) -> str:
    return "–" if not isinstance(value, int | float) or not math.isfinite(value) else f"{value:.3g}"


def _duration(seconds: Any) -> str:
    if not isinstance(seconds, int | float) or not math.isfinite(seconds):
        return "–"
    whole = int(seconds)
    return f"{whole // 3600}:{whole // 60 % 60:02d}:{whole % 60:02d}"


def answer_jobs(answer: Mapping[str, Any]) -> list[JobRecord | str]:
    """The jobs of one answer read by the one parser; an entry that is no job record is one line
    saying so (the daemon's JSON stays as it was for ``--json``)."""
    out: list[JobRecord | str] = []
    for data in (answer.get("jobs") or []) if answer["ok"] else []:
        try:
            out.append(JobRecord.from_dict(data))
        except ValueError as error:
            out.append(f"unreadable job entry: {error}")
    return out


def _job_line(node: str, job: JobRecord) -> str:
    started = datetime.fromtimestamp(job.t_start_ns / 1e9).strftime("%m-%d %H:%M") \
        if job.t_start_ns is not None else "–"
    peaks = [v for c, v in job.peak_power_w.items() if is_dram_channel(c) and math.isfinite(v)]
    return (f"{node:<10}{job.job_id[:9]:<10}{(job.user or '–')[:7]:<8}"
            f"{started:<12}{_duration(job.duration_s):>9}{_fmt(job.dram_energy_j):>9}"
            f"{_fmt(job.dram_above_baseline_j):>8}{_fmt(job.dram_mean_power_w):>7}"
            f"{_fmt(max(peaks) if peaks else None):>7}")


def table(answers: Sequence[dict[str, Any]]) -> list[str]:
    """The human table, 80 columns: one line per job and node (the job's state and status under it
    when it is still running or not fully measured); a line per node that did not answer or has no
    jobs. Peak W is the highest sample of any one DIMM pair (a job's whole-node peak is not known)."""
    lines = [f"{'node':<10}{'job':<10}{'user':<8}{'started':<12}{'duration':>9}{'DRAM J':>9}"
             f"{'>idle J':>8}{'mean W':>7}{'peak W':>7}"]
    for answer in answers:
        node = str(answer["node"])[:9]
        if not answer["ok"]:
            lines.append(f"{node:<10}{answer['error']}")
            continue
        if not answer["jobs"]:
            lines.append(f"{node:<10}(no jobs on this node)" if answer.get("op") == "job.list"
                         else f"{node:<10}(no such job on this node)")
        for job in answer_jobs(answer):
            if isinstance(job, str):
                lines.append(f"{node:<10}{job}")
                continue
            lines.append(_job_line(node, job))
            status = job.status or "ok"
            if job.state != "done" or status != "ok":
                lines.append(f"{'':<10}{job.state}: {status}")
    return lines


def total_line(answers: Sequence[dict[str, Any]]) -> str | None:
    """One job over several nodes: the sum of its DRAM energy (unknown when a node did not answer or
    does not know it); None for fewer than two nodes."""
    if len(answers) < 2:
        return None
    firsts = [next(iter(answer_jobs(a)), None) for a in answers]
    values = [job.dram_energy_j if isinstance(job, JobRecord) else math.nan for job in firsts]
    known = [v for v in values if math.isfinite(v)]
    total = sum(known) if len(known) == len(values) else math.nan
    note = "" if math.isfinite(total) else f"  (unknown: {len(values) - len(known)} of {len(values)} nodes missing)"
    return f"{'total':<10}{'':<10}{'':<8}{'':<12}{'':>9}{_fmt(total):>9}{note}"


def model_lines(answers: Sequence[dict[str, Any]]) -> list[str]:
    """Under ``--job``: each node's modelled DRAM energy by component (from the memory-controller
    counters), the calibrated split when the daemon has a fit, else the datasheet's; or, for a job
    that has ended, why there is none."""
    lines = []
    for answer in answers:
        for job in answer_jobs(answer):
            if isinstance(job, str):
                continue  # the table said so
            model = job.model
            if model is None:
                if job.state != "running":  # a running job is modelled when it stops: nothing to say yet
                    lines.append(f"{answer['node']:<10}model: – ({job.model_error or 'none'})")
                continue
            calibrated = (model.get("split_j") or {}).get("calibrated")
            which, split = ("calibrated", calibrated) if calibrated else ("datasheet", (model.get("split_j") or {})
                                                                         .get("datasheet") or {})
            parts = ", ".join(f"{kind.replace('_', '-')} {_fmt(value)}" for kind, value in split.items())
            counts = model.get("counts") or {}
            lines.append(f"{answer['node']:<10}model from counters: datasheet {_fmt(model.get('datasheet_j'))} J, "
                         f"calibrated {_fmt(model.get('calibrated_j'))} J over {_fmt(model.get('window_s'))} s "
                         f"({_count(counts.get('act'))} ACT, {_count(counts.get('rd'))} RD, "
                         f"{_count(counts.get('wr'))} WR)")
            lines.append(f"{'':<10}by component ({which}, J): {parts}")
            currents = model.get("currents")
            if isinstance(currents, Mapping) and currents.get("text"):
                lines.append(f"{'':<10}currents: {currents['text']}")
    return lines


def _run(args: argparse.Namespace) -> int:
    if not (args.timeout > 0 and math.isfinite(args.timeout)):
        raise InputError(f"--timeout {args.timeout!r}: expected seconds > 0")
    if not 1 <= args.limit <= 1000:
        raise InputError(f"--limit {args.limit}: expected 1..1000")
    from hdeem_watch.wire.protocol import ProtocolError, dumps
    from hdeem_watch.wire.requests import job_id_arg

    request: dict[str, Any] = {}
    if args.job is not None:
        try:
            request["job_id"] = job_id_arg(args.job)
        except ProtocolError:
            raise InputError(f"--job {args.job!r}: expected a SLURM job id such as 4242") from None
    op = "job.get" if args.job is not None and not (args.user or args.since) else "job.list"
    if op == "job.list":
        request["limit"] = args.limit
        if args.user:
            request["user"] = args.user
        if args.since:
            request["since_ns"] = parse_since(args.since)
    answers = [{**a, "op": op} for a in query(targets(args), op, request, timeout_s=args.timeout,
                                               keys=client_kwargs(curve_keys(args)))]
    if args.json:
        sys.stdout.write(dumps({"nodes": answers}).decode() + "\n")
    else:
        lines = table(answers)
        total = total_line(answers) if op == "job.get" else None
        if total is not None:
            lines.append(total)
        if op == "job.get":
            lines += model_lines(answers)
        print("\n".join(lines))
    return 0 if all(a["ok"] for a in answers) else 1
