"""Read a RUNS.json (the input of ``hdeem-watch calibrate``) into
:class:`~hdeem_watch.report.records.ReportData`, fitting it the way ``calibrate`` does by default.

The runs are read by :func:`hdeem_watch.calibrate.runs_file.read_runs_file`; their command
statistics (for the energy-by-component figure) are read again from each run's ``stats`` or
``trace``. A run named ``<kernel>-<threads>t`` (e.g. ``triad-24t``) is grouped by kernel and thread
count; any other name is its own kernel. A RUNS.json has no fit history, baselines or jobs.

Example::

    data = read_runs("RUNS.json")
    data.fit.error.loo           # leave-one-out mean |relative error|
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

from hdeem_watch.errors import InputError
from hdeem_watch.fit_record import FitRecord
from hdeem_watch.report.analysis import model_currents
from hdeem_watch.report.records import FitEntry, ReportData, RunRow

_LABEL = re.compile(r"^(?P<kernel>[A-Za-z_][\w]*?)[-_ ](?P<threads>\d+)t$")


def kernel_and_threads(name: str) -> tuple[str, int]:
    """``"triad-24t"`` → ``("triad", 24)``; ``"idle"`` → ``("idle", 0)``; anything else → ``(name, 0)``.

    Example:
        >>> kernel_and_threads("copy_12t"), kernel_and_threads("idle-24t"), kernel_and_threads("warm up")
        (('copy', 12), ('idle', 24), ('warm up', 0))
    """
    match = _LABEL.match(name.strip())
    if match:
        return match.group("kernel").lower(), int(match.group("threads"))
    return name.strip().lower(), 0


def read_runs(path: str | Path) -> ReportData:
    """Read and fit a RUNS.json.

    Raises:
        InputError: anything ``hdeem-watch calibrate`` would refuse, in the same words.
    """
    from hdeem_watch.calibrate.fit import fit

    path = Path(path)
    spec, observations = read_runs_file(path)
    result = FitRecord.from_dict(fit(observations, spec).to_dict())
    datasheet, _ = model_currents(spec, None)
    raw_runs = json.loads(path.read_text(encoding="utf-8"))["runs"]
    rows = []
    for i, (obs, entry, raw) in enumerate(zip(observations, result.runs, raw_runs)):
        kernel, threads = kernel_and_threads(obs.name)
        loo = entry.get("loo_j")
        rows.append(RunRow(
            run_id=f"run[{i}]", name=obs.name, kernel=kernel, threads=threads, t_ns=int(obs.time_ns),
            window_s=float(obs.window_s), measured_j=float(obs.measured_j),
            datasheet_j=float(obs.predicted_j(datasheet)), calibrated_j=float(entry["after_j"]),
            loo_j=math.nan if loo is None else float(loo),
            stats_groups=((_stats(spec, raw, obs.name, path.resolve().parent), float(raw.get("scale", 1.0))),)))
    notes = ("a RUNS.json has no fit history, idle baselines or job records",)
    return ReportData(source=f"RUNS.json {path}", spec=spec, runs=tuple(rows), fit=result,
                      fit_history=(FitEntry(t_ns=max((r.t_ns for r in rows), default=0), run_id=None, fit=result),),
                      notes=notes)


def read_runs_file(path: Path) -> tuple[Any, list[Any]]:
    """:func:`hdeem_watch.calibrate.runs_file.read_runs_file` (imported when used)."""
    from hdeem_watch.calibrate.runs_file import read_runs_file as read

    return read(path)


def _stats(spec: Any, run: Any, name: str, base: Path) -> Any:
    """The command statistics of one RUNS.json run (already validated by ``read_runs_file``)."""
    from hdeem_watch.dram.stats import CommandStats

    if "stats" in run:
        return CommandStats.from_dict(run["stats"], where=f"run {name!r}: stats")
    from hdeem_watch.dram.command_trace import read_command_trace
    from hdeem_watch.dram.trace_state import trace_stats

    trace = Path(run["trace"])
    try:
        return trace_stats(spec, read_command_trace(trace if trace.is_absolute() else base / trace))
    except InputError as error:
        raise InputError(f"run {name!r}: {error}") from None
