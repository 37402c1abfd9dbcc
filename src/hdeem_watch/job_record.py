"""One SLURM job as the daemon records it, and the one parser of its JSON form.

A job is opened by ``job.start`` (the Prolog) and closed by ``job.stop`` (the Epilog); the daemon
measures it in *segments*, one per daemon session that saw it, and derives the totals
(``hdeem_watch.daemon.jobs.records``: ``with_segments``, ``finish``). The same record is the
``job.start``/``job.stop``/``job.get`` reply, a row of the state's ``jobs`` table, and — as a
summary without its segments (``n_segments`` instead, the counters reduced to their status) — the
``job`` topic's body and a ``job.list`` entry. The CLI (``jobs``), the SLURM hooks and the report
read every one of these forms through :meth:`JobRecord.from_dict`; nobody else parses a job's JSON.

The parser is tolerant: a field that is missing or of the wrong type becomes unknown (NaN for
energies and durations, None for counts and times, never 0) and is named in
:attr:`JobRecord.problems`; ``strict=True`` refuses such a record instead. A record remembers the
keys it was read with, in their order, and keeps those it does not know, so :meth:`JobRecord.to_dict`
writes back the same JSON, byte for byte, as the daemon wrote it — full record and summary alike.

Example:
    >>> job = JobRecord.from_dict({"job_id": "42", "node": "n1", "state": "done", "dram_energy_j": None,
    ...                            "measured_s": 2.0, "status": "ok", "n_segments": 1})
    >>> job.job_id, math.isnan(job.dram_energy_j), job.segment_count, job.problems[0]
    ('42', True, 1, 't_start_ns: missing')
"""

from __future__ import annotations

import copy
import dataclasses
import math
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

from hdeem_watch.record_fields import FieldReader, is_number

JobState = Literal["running", "done", "interrupted"]
JOB_STATES: tuple[str, ...] = typing.get_args(JobState)

#: A full record's keys, in the order the daemon writes them.
JOB_FIELDS = ("job_id", "node", "user", "uid", "nodes", "cpus", "t_start_ns", "state", "t_stop_ns", "exit_code",
              "segments", "energy_j", "dram_energy_j", "above_baseline_j", "dram_above_baseline_j", "baseline_w",
              "baseline_status", "mean_power_w", "peak_power_w", "measured_s", "unmeasured_s", "duration_s", "status",
              "shared_with", "late_stop_s", "counters", "model", "model_error")
#: The summary's count of segments (``job_summary``: the topic's body, a ``job.list`` entry).
SUMMARY_FIELDS = ("n_segments",)
#: Fields every form has; another one missing is not a problem (older records lack some).
_REQUIRED = ("node", "t_start_ns", "dram_energy_j", "measured_s", "status")
_CHANNEL_VALUES = ("energy_j", "above_baseline_j", "baseline_w", "mean_power_w", "peak_power_w")


@dataclass(frozen=True, slots=True)
class JobArgs:
    """Validated arguments of ``job.start`` (``hdeem_watch.daemon.jobs.records.parse_job_args``)."""

    job_id: str
    user: str
    uid: int | None
    nodes: tuple[str, ...]
    cpus: int | None


@dataclass(frozen=True, slots=True)
class Segment:
    """What one daemon session measured of a job.

    Attributes:
        t_start_ns, t_stop_ns: wall clock at the segment's start and end (its last checkpoint while
            open).
        energy_j: per channel, J over the segment (NaN = unknown).
        spans_s: per channel, seconds of sample time the energy covers.
        samples_ns: per channel ``[last sample time before the segment, last sample time in it]``:
            the samples with ``first < t <= last`` make up the energy.
        peak_w: per channel, the highest sample in the segment.
        open: the segment was still being measured when it was saved (a checkpoint).
        counters: the memory controller's counts over the segment
            (:meth:`~hdeem_watch.daemon.counters.windows.CounterWindows.finish_window`; None with
            counters off or without a counter read at its start).
    """

    t_start_ns: int
    t_stop_ns: int
    energy_j: dict[str, float]
    spans_s: dict[str, float]
    samples_ns: dict[str, list[int | None]]
    peak_w: dict[str, float] = field(default_factory=dict)
    open: bool = False
    counters: dict[str, Any] | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Segment:
        """Inverse of :meth:`to_dict` (null → NaN).

        Raises:
            KeyError, TypeError, ValueError: not a segment.
        """
        def floats(key: str) -> dict[str, float]:
            values = data.get(key) or {}
            return {str(c): math.nan if v is None else float(v) for c, v in values.items()}

        return cls(t_start_ns=int(data["t_start_ns"]), t_stop_ns=int(data["t_stop_ns"]), energy_j=floats("energy_j"),
                   spans_s=floats("spans_s"), samples_ns={str(c): list(v) for c, v in (data.get("samples_ns") or {}).items()},
                   peak_w=floats("peak_w"), open=bool(data.get("open", False)),
                   counters=dict(data["counters"]) if isinstance(data.get("counters"), Mapping) else None)


@dataclass(frozen=True, slots=True)
class JobRecord:
    """One job on this node, from ``job.start`` to ``job.stop`` (or its interruption).

    Energies are per channel in J (NaN = unknown, never 0); ``dram_*`` the sums over the DRAM
    channels. The totals (``energy_j`` … ``status``) are derived from the segments by the daemon.
    ``t_start_ns`` is None only in a record read without it (see :attr:`problems`).
    """

    job_id: str
    node: str
    user: str
    uid: int | None
    nodes: tuple[str, ...]
    cpus: int | None
    t_start_ns: int | None
    state: JobState = "running"
    t_stop_ns: int | None = None
    exit_code: int | str | None = None
    segments: tuple[Segment, ...] = ()
    energy_j: dict[str, float] = field(default_factory=dict)
    dram_energy_j: float = math.nan
    above_baseline_j: dict[str, float] = field(default_factory=dict)
    dram_above_baseline_j: float = math.nan
    baseline_w: dict[str, float] = field(default_factory=dict)
    baseline_status: str = "no baseline"
    mean_power_w: dict[str, float] = field(default_factory=dict)
    peak_power_w: dict[str, float] = field(default_factory=dict)
    measured_s: float = 0.0
    unmeasured_s: float = 0.0
    duration_s: float | None = None
    status: str = "ok"
    shared_with: tuple[str, ...] = ()
    late_stop_s: float = 0.0
    counters: dict[str, Any] | None = None
    model: dict[str, Any] | None = None
    model_error: str | None = None
    #: A summary's count of segments (None in a full record: see :attr:`segment_count`).
    n_segments: int | None = None
    #: Fields :meth:`from_dict` could not read, one line each (not sent).
    problems: tuple[str, ...] = field(default=(), compare=False, repr=False)
    #: The keys it was read with, in order (:meth:`to_dict` writes those).
    keys: tuple[str, ...] = field(default=JOB_FIELDS, compare=False, repr=False)
    #: Keys of the read form this version does not know, written back as they were.
    extra: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)

    @classmethod
    def start(cls, args: JobArgs, *, node: str, t_wall_ns: int) -> JobRecord:
        """The record of a job that just started."""
        return cls(job_id=args.job_id, node=node, user=args.user, uid=args.uid, nodes=args.nodes, cpus=args.cpus,
                   t_start_ns=int(t_wall_ns))

    @property
    def segment_count(self) -> int:
        """How many daemon sessions measured the job (a summary's ``n_segments``)."""
        return self.n_segments if self.n_segments is not None else len(self.segments)

    @property
    def dram_mean_power_w(self) -> float:
        """The DRAM energy over the measured time (W; NaN when either is unknown or no time)."""
        return self.dram_energy_j / self.measured_s if self.measured_s > 0 else math.nan

    def sharing(self, job_ids: typing.Iterable[str]) -> JobRecord:
        """A copy that also names ``job_ids`` as jobs that ran on the node at the same time."""
        merged = tuple(dict.fromkeys((*self.shared_with, *(j for j in job_ids if j != self.job_id))))
        return dataclasses.replace(self, shared_with=merged)

    def to_dict(self) -> dict[str, Any]:
        """The JSON-ready record (NaN stays NaN; the protocol encoder sends null), with the keys
        it was read with in their order."""
        known = dataclasses.asdict(self)
        known.update(nodes=list(self.nodes), shared_with=list(self.shared_with), segments=list(known["segments"]))
        written = JOB_FIELDS + SUMMARY_FIELDS
        return {key: known[key] if key in written else copy.deepcopy(self.extra[key])
                for key in self.keys if key in written or key in self.extra}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], *, strict: bool = False) -> JobRecord:
        """A record from any stored or sent form (see the module docstring).

        Raises:
            ValueError: not a job record at all (no string ``job_id``, no known ``state``), or with
                ``strict`` any field unreadable (the message names each).
        """
        if not isinstance(data, Mapping):
            raise ValueError(f"not a job record: {type(data).__name__}")
        job_id, state = data.get("job_id"), data.get("state")
        if not isinstance(job_id, str) or state not in JOB_STATES:
            raise ValueError(f"not a job record: job_id {repr(job_id)[:40]}, state {repr(state)[:40]}")
        r = _Reader(data)
        values: dict[str, Any] = {key: r.energies(key) for key in _CHANNEL_VALUES}
        record = cls(
            job_id=job_id, state=state, node=r.text("node"), user=r.text("user"), uid=r.integer("uid"),
            nodes=r.names("nodes"), cpus=r.integer("cpus"), t_start_ns=r.integer("t_start_ns"),
            t_stop_ns=r.integer("t_stop_ns"), exit_code=r.exit_code(), segments=r.segments(),
            dram_energy_j=r.real("dram_energy_j"), dram_above_baseline_j=r.real("dram_above_baseline_j"),
            baseline_status=r.text("baseline_status"), measured_s=r.real("measured_s"),
            unmeasured_s=r.real("unmeasured_s"), duration_s=r.optional_real("duration_s"), status=r.text("status"),
            shared_with=r.names("shared_with"), late_stop_s=r.real("late_stop_s"), counters=r.mapping("counters"),
            model=r.mapping("model"), model_error=r.optional_text("model_error"), n_segments=r.integer("n_segments"),
            keys=tuple(data), extra={k: v for k, v in data.items() if k not in JOB_FIELDS + SUMMARY_FIELDS},
            **values, problems=tuple(r.problems))
        if strict and record.problems:
            raise ValueError(f"job {job_id}: " + "; ".join(record.problems))
        return record


class _Reader(FieldReader):
    """Reads a job record's fields (:class:`~hdeem_watch.record_fields.FieldReader`). Null is
    unknown (no problem); an absent key is a problem only when in :data:`_REQUIRED`."""

    def __init__(self, data: Mapping[str, Any]) -> None:
        super().__init__(data, required=_REQUIRED)

    def text(self, key: str) -> str:
        return super().text(key) or ""

    def optional_text(self, key: str) -> str | None:
        return super().text(key)

    def names(self, key: str) -> tuple[str, ...]:
        value = self.value(key, lambda v: isinstance(v, list) and all(isinstance(n, str) for n in v),
                           "a list of names")
        return tuple(value or ())

    def energies(self, key: str) -> dict[str, float]:
        value = self.value(key, lambda v: isinstance(v, Mapping) and all(x is None or is_number(x) for x in v.values()),
                           "an object of numbers")
        return {str(c): math.nan if v is None else float(v) for c, v in (value or {}).items()}

    def exit_code(self) -> int | str | None:
        return self.value("exit_code", lambda v: isinstance(v, str | int) and not isinstance(v, bool),
                          "an integer or SLURM's \"0:15\"")

    def segments(self) -> tuple[Segment, ...]:
        raw = self.value("segments", lambda v: isinstance(v, list), "a list")
        out = []
        for i, entry in enumerate(raw or ()):
            try:
                out.append(Segment.from_dict(entry))
            except (KeyError, TypeError, ValueError, AttributeError) as error:
                self.problems.append(f"segments[{i}]: not a segment ({error!r}; left out)")
        return tuple(out)
