"""Runs: what a benchmark run announced, and the energy each channel used during it.

A run is opened by ``run.start`` and closed by ``run.stop``. At both ends the daemon polls the
source once more and takes its *cumulative* energies, so the window's energy per channel is an
exact difference of the source's own totals: nothing is lost between polls, whatever the poll rate
or the sample losses. The window's duration is measured on the source's clock (the source's time
for a sped-up sim or replay).

A run is a typed :class:`~hdeem_watch.run_record.RunRecord` (shared with the report, the TUI and
the calibrator); it becomes a JSON-ready dict only at the edge (``RunRecord.to_dict`` for the
``run`` topic, the store and ``run.stop``; :func:`run_summary` for ``runs.list``). Its ``state``
goes ``running`` → ``modelling`` (the window closed; the model and the refit are pending) →
``done``, or ``aborted``.

Example:
    >>> args = parse_run_args({"kernel": "triad", "threads": 24, "elements": 1000})
    >>> rec = started_run("r1", args, t_wall_ns=5, node="n1")
    >>> rec.state, rec.kernel
    ('running', 'triad')
    >>> window_energy({"DDR_AB": 10.0, "CPU0": 1.0}, {"DDR_AB": 12.5, "CPU0": float("nan")})
    {'DDR_AB': 2.5, 'CPU0': nan}
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from hdeem_watch.run_record import NO_TRAFFIC_KERNELS, OPAQUE_KERNEL, RunRecord
from hdeem_watch.wire.protocol import ProtocolError, quoted

#: Largest number of samples kept per channel for one run (≈ 3 h at 100 Sa/s).
MAX_RUN_SAMPLES = 1_000_000
#: Largest ``repeat`` of a run.
MAX_REPEAT = 1_000_000
#: Threads allowed per logical CPU of the node (oversubscribed runs are legitimate, absurd ones not).
THREADS_PER_CPU = 4
#: Arrays of doubles a STREAM-like kernel touches at most (triad: a, b, c).
KERNEL_ARRAYS = 3
#: The limits assume at least this many logical CPUs and bytes of memory, so that a simulated node
#: (2 × 12 Haswell cores, 48 logical CPUs, 64 GiB) can be driven from a small machine.
MIN_CPUS = 64
MIN_MEMORY_BYTES = 128 << 30

@dataclass(frozen=True)
class RunLimits:
    """Bounds of the numbers ``run.start`` accepts.

    Attributes:
        max_threads: threads (logical CPUs × :data:`THREADS_PER_CPU`; see :data:`MIN_CPUS`).
        max_elements: elements per array (all of the node's memory in :data:`KERNEL_ARRAYS` arrays;
            see :data:`MIN_MEMORY_BYTES`).
        max_repeat: passes over the arrays.
    """

    max_threads: int
    max_elements: int
    max_repeat: int = MAX_REPEAT

    @classmethod
    def of_this_node(cls) -> RunLimits:
        """The limits of the machine this process runs on."""
        import psutil

        cpus = max(os.cpu_count() or 1, MIN_CPUS)
        memory = max(int(psutil.virtual_memory().total), MIN_MEMORY_BYTES)
        return cls(max_threads=cpus * THREADS_PER_CPU, max_elements=max(1, memory // (8 * KERNEL_ARRAYS)))


@dataclass(frozen=True)
class RunArgs:
    """Validated arguments of ``run.start``."""

    kernel: str
    name: str
    threads: int
    elements: int
    repeat: int
    metadata: dict[str, Any]

    @property
    def moves_no_traffic(self) -> bool:
        """Whether this is an idle run (no memory traffic)."""
        return self.kernel in NO_TRAFFIC_KERNELS


def _int_arg(args: Mapping[str, Any], key: str, default: int, minimum: int, maximum: int) -> int:
    value = args.get(key, default)
    if value is None:
        value = default
    if isinstance(value, bool) or not isinstance(value, int) or not minimum <= value <= maximum:
        raise ProtocolError(f"args.{key} = {quoted(value)}: expected an integer in [{minimum}, {maximum}]", code="bad-args")
    return int(value)


def _text_arg(value: Any, key: str) -> str:
    if not isinstance(value, str):
        raise ProtocolError(f"args.{key} = {quoted(value)}: expected a string", code="bad-args")
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:
        raise ProtocolError(f"args.{key}: not valid text (a lone surrogate?)", code="bad-args") from None
    return value


def parse_run_args(args: Mapping[str, Any], limits: RunLimits | None = None) -> RunArgs:
    """Validate ``run.start`` arguments: integers only where integers are meant, within ``limits``.

    Raises:
        ProtocolError: code ``bad-args`` naming the argument.
    """
    limits = limits or RunLimits(max_threads=1 << 20, max_elements=1 << 50)
    kernel = args.get("kernel", OPAQUE_KERNEL)
    kernel = OPAQUE_KERNEL if kernel is None else kernel
    if not isinstance(kernel, str) or not kernel.strip():
        raise ProtocolError(f"args.kernel = {quoted(kernel)}: expected a kernel name (e.g. 'triad', 'idle')", code="bad-args")
    kernel = _text_arg(kernel, "kernel").strip().lower()
    name = args.get("name")
    name = kernel if name is None or name == "" else _text_arg(name, "name")  # [], {}, 0, false: refused
    metadata = args.get("metadata") or {}
    if not isinstance(metadata, dict):
        raise ProtocolError("args.metadata: expected an object", code="bad-args")
    return RunArgs(
        kernel=kernel,
        name=name[:200],
        threads=_int_arg(args, "threads", 1, 1, limits.max_threads),
        elements=_int_arg(args, "elements", 0, 0, limits.max_elements),
        repeat=_int_arg(args, "repeat", 1, 1, limits.max_repeat),
        metadata=metadata,
    )


def started_run(run_id: str, args: RunArgs, *, t_wall_ns: int, node: str) -> RunRecord:
    """The record of a run that just started."""
    return RunRecord(run_id=run_id, node=node, name=args.name, kernel=args.kernel, threads=args.threads,
                     elements=args.elements, repeat=args.repeat, metadata=args.metadata, t_start_ns=int(t_wall_ns))


#: The fields of a record that ``runs.list`` sends (the model and fit reduced to their figures).
SUMMARY_FIELDS = ("run_id", "node", "name", "kernel", "threads", "elements", "repeat", "metadata", "state",
                  "t_start_ns", "t_stop_ns", "window_s", "energy_j", "mean_power_w", "dram_energy_j", "model_error")
SUMMARY_MODEL_FIELDS = ("datasheet_j", "predicted_j", "calibrated_j", "fitted_j")


def run_summary(record: Mapping[str, Any]) -> dict[str, Any]:
    """The ``runs.list`` entry of a stored record: everything but the model's row and the full fit.

    Idempotent (a summary's summary is itself), a few hundred bytes instead of ~46 KB.

    >>> run_summary({"run_id": "r1", "model": {"datasheet_j": 3.0, "observation": {"x": 1}},
    ...              "fit": {"n_runs": 2, "error": {"after": 0.1}, "currents": {}}})["model"]
    {'datasheet_j': 3.0}
    """
    summary = {key: record[key] for key in SUMMARY_FIELDS if key in record}
    model = record.get("model")
    if isinstance(model, Mapping):
        summary["model"] = {k: model[k] for k in SUMMARY_MODEL_FIELDS if k in model}
    elif "model" in record:
        summary["model"] = None
    fit = record.get("fit")
    if isinstance(fit, Mapping):
        error = fit.get("error")
        summary["fit"] = {"n_runs": fit.get("n_runs"),
                          "error": {"after": error.get("after")} if isinstance(error, Mapping) else None}
    elif "fit" in record:
        summary["fit"] = None
    return summary


def window_energy(start_j: Mapping[str, float], stop_j: Mapping[str, float]) -> dict[str, float]:
    """Per-channel energy of a window from cumulative energies at its ends (NaN if either is unknown)."""
    result = {}
    for name, stop in stop_j.items():
        start = start_j.get(name, math.nan)
        result[name] = float(stop) - float(start) if math.isfinite(start) and math.isfinite(stop) else math.nan
    return result
