"""SLURM jobs as the daemon measures them: ``job.start``'s arguments and the record's totals over
its segments (pure; the record itself is :class:`hdeem_watch.job_record.JobRecord`).

A job is opened by ``job.start`` (the Prolog) and closed by ``job.stop`` (the Epilog). The daemon
integrates every channel over the job exactly as over a run window (the same
:class:`~hdeem_watch.daemon.book.windows.Window`: differences of the source's cumulative energies, cut at
the stop to the sample). A job's time is measured in *segments*: one per daemon session that saw it.
A daemon that stops (``kill -9`` included) keeps the job's energy up to its last checkpoint; the
restarted daemon opens a new segment, and the time between is an *unmeasured* gap that the record
states (``unmeasured_s``, ``status``) instead of hiding. Energies are summed over segments; a
channel unknown in any segment is unknown (NaN) in the sum, never 0.

Above-baseline energy per channel is ``energy − baseline power × measured seconds`` with the node's
kept idle baseline; without a baseline it is NaN and ``baseline_status`` names the channels.

With a counter source on, each segment carries the memory controller's counts over it
(``counters``), the record their sum over segments
(:func:`~hdeem_watch.calibrate.counter_model.sum_counters`), and a finished job the modelled energy by
component (``model``, ``source = "counters"``; computed on the model worker). Without counters
``model`` is None and ``model_error`` says why, never zeros.

Example:
    >>> args = parse_job_args({"job_id": "42", "user": "alice", "uid": 1000, "nodes": ["n1"], "cpus": 4})
    >>> job = JobRecord.start(args, node="n1", t_wall_ns=0)
    >>> seg = Segment(t_start_ns=0, t_stop_ns=2_000_000_000, energy_j={"DDR_AB": 10.0}, spans_s={"DDR_AB": 2.0},
    ...               samples_ns={"DDR_AB": [0, 2_000_000_000]}, peak_w={"DDR_AB": 6.0})
    >>> done = finish(with_segments(job, [seg]), state="done", t_wall_ns=2_000_000_000, dram_channels=("DDR_AB",),
    ...               baselines_w={"DDR_AB": 4.0})
    >>> done.energy_j, done.above_baseline_j, done.mean_power_w, done.status
    ({'DDR_AB': 10.0}, {'DDR_AB': 2.0}, {'DDR_AB': 5.0}, 'ok')
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import re
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from hdeem_watch.calibrate.counter_model import sum_counters
from hdeem_watch.job_record import JobArgs, JobRecord, JobState, Segment
from hdeem_watch.run_record import total_energy
from hdeem_watch.wire.protocol import ProtocolError, quoted
from hdeem_watch.wire.requests import job_id_arg

#: Most node names a ``job.start`` may list.
MAX_JOB_NODES = 100_000


def _optional_int(args: Mapping[str, Any], key: str, maximum: int) -> int | None:
    value = args.get(key)
    if value is None:
        return None
    if isinstance(value, str) and value.isdigit():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= maximum:
        raise ProtocolError(f"args.{key} = {quoted(value)}: expected an integer in [0, {maximum}]", code="bad-args")
    return int(value)


def parse_job_args(args: Mapping[str, Any]) -> JobArgs:
    """Validate ``job.start`` arguments (``job_id`` required; ``user``, ``uid``, ``nodes``, ``cpus``).

    ``nodes`` is a list of node names or one SLURM hostlist string (kept as given).

    Raises:
        ProtocolError: code ``bad-args`` naming the argument.
    """
    job_id = job_id_arg(args.get("job_id"))
    user = args.get("user") or ""
    if not isinstance(user, str) or len(user) > 256:
        raise ProtocolError(f"args.user = {quoted(user)}: expected a user name", code="bad-args")
    nodes = args.get("nodes") or []
    if isinstance(nodes, str):
        nodes = [nodes]
    if (not isinstance(nodes, list) or len(nodes) > MAX_JOB_NODES
            or not all(isinstance(n, str) and 0 < len(n) <= 4096 for n in nodes)):
        raise ProtocolError("args.nodes: expected a list of node names (or a SLURM hostlist string)",
                            code="bad-args")
    return JobArgs(job_id=job_id, user=user, uid=_optional_int(args, "uid", 2**32 - 1), nodes=tuple(nodes),
                   cpus=_optional_int(args, "cpus", 1 << 24))


def exit_code_arg(value: Any) -> int | str | None:
    """The Epilog's ``SLURM_JOB_EXIT_CODE`` (an integer, or SLURM's ``"0:15"`` form), or None."""
    if value is None:
        return None
    if isinstance(value, int) and not isinstance(value, bool):
        return value
    if isinstance(value, str) and re.fullmatch(r"-?\d{1,10}(:\d{1,10})?", value):
        return int(value) if ":" not in value else value
    raise ProtocolError(f"args.exit_code = {quoted(value)}: expected an integer (SLURM_JOB_EXIT_CODE)", code="bad-args")


def _sum(values: Iterable[float]) -> float:
    items = list(values)
    return float(sum(items)) if items else math.nan


def with_segments(job: JobRecord, segments: Sequence[Segment], *, dram_channels: Sequence[str] = (),
                  baselines_w: Mapping[str, float] | None = None, t_wall_ns: int | None = None) -> JobRecord:
    """A copy of ``job`` with these segments and the totals over them (a running job's energy so far)."""
    return _totals(dataclasses.replace(job, segments=tuple(segments)), dram_channels, baselines_w or {}, t_wall_ns)


def finish(job: JobRecord, *, state: JobState, t_wall_ns: int, dram_channels: Sequence[str],
           baselines_w: Mapping[str, float], exit_code: int | str | None = None) -> JobRecord:
    """The finished record (``done`` or ``interrupted``) with its totals."""
    closed = tuple(dataclasses.replace(s, open=False) for s in job.segments)
    ended = dataclasses.replace(job, state=state, t_stop_ns=int(t_wall_ns), segments=closed,
                                exit_code=exit_code if exit_code is not None else job.exit_code)
    return _totals(ended, dram_channels, baselines_w, t_wall_ns)


def _totals(job: JobRecord, dram_channels: Sequence[str], baselines_w: Mapping[str, float],
            t_wall_ns: int | None) -> JobRecord:
    """Sum the segments: energies, spans, peaks, baselines, the unmeasured gaps."""
    segments = job.segments
    channels = list(dict.fromkeys(c for s in segments for c in s.energy_j))
    # A segment without samples of a channel (a daemon killed right after a start) adds no time
    # and no energy; a channel no segment sampled stays unknown.
    energy = {c: _sum(s.energy_j.get(c, math.nan) for s in segments if s.spans_s.get(c, 0.0) > 0) for c in channels}
    spans = {c: float(sum(s.spans_s.get(c, 0.0) for s in segments)) for c in channels}
    peaks = {c: max((s.peak_w[c] for s in segments if c in s.peak_w), default=math.nan) for c in channels}
    mean = {c: energy[c] / spans[c] if spans[c] > 0 else math.nan for c in channels}
    baseline = {c: float(baselines_w.get(c, math.nan)) for c in channels}
    above = {c: energy[c] - baseline[c] * spans[c] if math.isfinite(baseline[c]) else math.nan for c in channels}
    missing = [c for c in channels if not math.isfinite(baseline[c])]
    dram = [c for c in dram_channels if c in energy]
    gap_ns = 0
    start = job.t_start_ns if job.t_start_ns is not None else (segments[0].t_start_ns if segments else None)
    edges = ([(start, start)] if start is not None else []) + [(s.t_start_ns, s.t_stop_ns) for s in segments]
    if job.state != "running" and job.t_stop_ns is not None:
        edges.append((job.t_stop_ns, job.t_stop_ns))
    for (_a0, a1), (b0, _b1) in itertools.pairwise(edges):
        gap_ns += max(0, b0 - a1)
    measured = max((spans[c] for c in dram), default=max(spans.values(), default=0.0))
    status = "ok"
    if not segments:
        status = "not measured: no daemon session saw this job"
    elif gap_ns > 0:
        status = f"gap: {gap_ns / 1e9:.1f} s not measured (the daemon was down or restarted)"
    if job.late_stop_s > 0:
        late = f"late stop: measured {job.late_stop_s:.1f} s past the job's end (the Epilog's stop came late)"
        status = late if status == "ok" else f"{status}; {late}"
    end = job.t_stop_ns if job.t_stop_ns is not None else t_wall_ns
    counters = sum_counters([s.counters for s in segments]) if segments else None
    model_error = job.model_error
    if job.model is None:
        model_error = model_reason(job.state, counters)
    return dataclasses.replace(
        job, energy_j=energy, dram_energy_j=total_energy(energy, dram) if dram else math.nan,
        above_baseline_j=above, dram_above_baseline_j=total_energy(above, dram) if dram else math.nan,
        baseline_w=baseline, baseline_status="ok" if not missing else "no baseline: " + ", ".join(missing),
        mean_power_w=mean, peak_power_w=peaks, measured_s=float(measured), unmeasured_s=gap_ns / 1e9,
        duration_s=None if end is None or start is None else (end - start) / 1e9, status=status, counters=counters,
        model_error=model_error)


def model_reason(state: str, counters: Mapping[str, Any] | None) -> str:
    """Why a job record has no ``model`` (yet)."""
    if counters is None:
        return ("no counters: the daemon counts no memory-controller commands (counters = 'none'), "
                "or no counter read covered this job's window")
    if state == "running":
        return "running: the model by component is computed from the counters when the job ends"
    return "not modelled yet"


def job_summary(record: Mapping[str, Any]) -> dict[str, Any]:
    """A ``job.list`` entry: the record without its per-segment detail (a count instead) and without
    the counters' per-channel counts (8 channels × ~17 events per job in every ``status`` reply;
    ``job.get`` has them): the counters' status and window stay, and the model by component.

    Example:
        >>> s = job_summary({"job_id": "7", "segments": [{}, {}], "counters": {"status": "ok", "channels": {"S0.imc0": {}}}})
        >>> s["n_segments"], s["counters"]
        (2, {'status': 'ok', 'n_channels': 1})
    """
    summary = {k: v for k, v in record.items() if k != "segments"}
    summary["n_segments"] = len(record.get("segments") or [])
    counters = record.get("counters")
    if isinstance(counters, Mapping) and "channels" in counters:
        channels = counters["channels"]
        summary["counters"] = {**{k: v for k, v in counters.items() if k != "channels"},
                               "n_channels": len(channels) if isinstance(channels, Mapping) else 0}
    return summary
