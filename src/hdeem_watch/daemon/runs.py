"""Run windows: what a benchmark run announced, and the energy each channel used during it.

A run is opened by ``run.start`` and closed by ``run.stop``. At both ends the daemon polls the
source once more and takes its *cumulative* energies, so the window's energy per channel is an
exact difference of the source's own totals: nothing is lost between polls, whatever the poll rate
or the sample losses. The window's duration is measured on the source's monotonic clock (the
source's time for a sped-up sim or replay).

Run records are plain JSON-ready dicts (the ``run`` topic and ``runs.list`` send them as they are);
this module builds and completes them with pure functions.

Example:
    >>> args = parse_run_args({"kernel": "triad", "threads": 24, "elements": 1000})
    >>> rec = new_record("r1", args, t_wall_ns=5, node="n1")
    >>> rec["state"], rec["kernel"]
    ('running', 'triad')
    >>> window_energy({"DDR_AB": 10.0, "CPU0": 1.0}, {"DDR_AB": 12.5, "CPU0": float("nan")})
    {'DDR_AB': 2.5, 'CPU0': nan}
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from hdeem_watch.daemon.protocol import ProtocolError

#: The kernel name of an idle run (no memory traffic; pins the standby currents).
IDLE_KERNELS = ("idle", "sleep")
#: Largest number of samples kept per channel for one run (≈ 3 h at 100 Sa/s).
MAX_RUN_SAMPLES = 1_000_000


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
    def idle(self) -> bool:
        """Whether this is an idle run (no memory traffic)."""
        return self.kernel in IDLE_KERNELS


def _int_arg(args: Mapping[str, Any], key: str, default: int, minimum: int) -> int:
    value = args.get(key, default)
    if value is None:
        value = default
    if isinstance(value, bool) or not isinstance(value, int | float) or value != int(value) or value < minimum:
        raise ProtocolError(f"args.{key} = {value!r}: expected an integer >= {minimum}", code="bad-args")
    return int(value)


def parse_run_args(args: Mapping[str, Any]) -> RunArgs:
    """Validate ``run.start`` arguments.

    Raises:
        ProtocolError: code ``bad-args`` naming the argument.
    """
    kernel = args.get("kernel")
    if not isinstance(kernel, str) or not kernel.strip():
        raise ProtocolError(f"args.kernel = {kernel!r}: expected a kernel name (e.g. 'triad', 'idle')", code="bad-args")
    kernel = kernel.strip().lower()
    name = args.get("name") or kernel
    if not isinstance(name, str):
        raise ProtocolError(f"args.name = {name!r}: expected a string", code="bad-args")
    metadata = args.get("metadata") or {}
    if not isinstance(metadata, dict):
        raise ProtocolError("args.metadata: expected an object", code="bad-args")
    return RunArgs(
        kernel=kernel,
        name=name[:200],
        threads=_int_arg(args, "threads", 1, 1),
        elements=_int_arg(args, "elements", 0, 0),
        repeat=_int_arg(args, "repeat", 1, 1),
        metadata=metadata,
    )


def new_record(run_id: str, args: RunArgs, *, t_wall_ns: int, node: str) -> dict[str, Any]:
    """The record of a run that just started."""
    return {
        "run_id": run_id,
        "node": node,
        "name": args.name,
        "kernel": args.kernel,
        "threads": args.threads,
        "elements": args.elements,
        "repeat": args.repeat,
        "metadata": args.metadata,
        "state": "running",
        "t_start_ns": int(t_wall_ns),
        "t_stop_ns": None,
        "window_s": None,
        "energy_j": None,
        "mean_power_w": None,
        "dram_energy_j": None,
        "model": None,
        "model_error": None,
        "fit": None,
        "samples_ns": None,
    }


def window_energy(start_j: Mapping[str, float], stop_j: Mapping[str, float]) -> dict[str, float]:
    """Per-channel energy of a window from cumulative energies at its ends (NaN if either is unknown)."""
    result = {}
    for name, stop in stop_j.items():
        start = start_j.get(name, math.nan)
        result[name] = float(stop) - float(start) if math.isfinite(start) and math.isfinite(stop) else math.nan
    return result


def total_energy(energy_j: Mapping[str, float], channels: Iterable[str]) -> float:
    """Sum over ``channels`` (NaN when any of them is unknown or none is present)."""
    values = [energy_j.get(c, math.nan) for c in channels]
    if not values:
        return math.nan
    return float(sum(values))


def finish_record(
    record: Mapping[str, Any],
    *,
    energy_j: Mapping[str, float],
    window_s: float,
    dram_channels: Iterable[str],
    t_wall_ns: int,
    spans_s: Mapping[str, float] | None = None,
    aborted: bool = False,
) -> dict[str, Any]:
    """A copy of ``record`` closed with its measured energies.

    ``spans_s`` gives each channel's own duration for its mean power (default ``window_s``).
    """
    done = dict(record)
    done["state"] = "aborted" if aborted else "done"
    done["t_stop_ns"] = int(t_wall_ns)
    done["window_s"] = float(window_s)
    done["energy_j"] = dict(energy_j)
    spans = spans_s or {}
    done["mean_power_w"] = {}
    for channel, energy in energy_j.items():
        span = spans.get(channel, window_s)
        done["mean_power_w"][channel] = energy / span if span > 0 else math.nan
    done["dram_energy_j"] = total_energy(energy_j, dram_channels)
    return done
