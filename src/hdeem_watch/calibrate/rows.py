"""From a measured run to a calibration row (DESIGN.md §4).

The command counts (ACT, PRE, RD, WR, ... per rank) come from the model of the run (a command trace,
or the model of the announced kernel); the background residency is the model's fraction of each
state times the *measured* window, and refresh is stretched to the measured window too (the device
refreshes whatever the kernel does). An idle run is command statistics with no commands; if even
its window is empty (``cycles_total == 0``) the rank is taken as precharged standby for the whole
window with a refresh every ``REFI``. ``scale`` multiplies the row (e.g. the number of identical
channels or DIMMs the measured energy covers).

The energy model's linear decomposition (:func:`hdeem_watch.dram.energy.energy_columns`) turns the
stretched statistics into one column per current; the fit later moves the currents it does not
calibrate into the constant.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from hdeem_watch.calibrate.observation import Observation, check_measured
from hdeem_watch.dram.stats import COUNT_FIELDS, CommandStats, RankStats
from hdeem_watch.errors import InputError

_STRETCHED = ("cycles_act", "cycles_pre", "cycles_pdna", "cycles_pdnp", "cycles_sref", "bank_active_cycles")


def stretch_stats(spec: Any, stats: CommandStats, window_s: float, *, name: str = "run") -> CommandStats:
    """``stats`` with its state residency and refreshes stretched to a window of ``window_s``.

    Args:
        spec: the memspec (``tck_s``, ``timings["REFI"]``).
        stats: the model's statistics (any window length).
        window_s: the measured window in seconds, > 0.
        name: the run's name, for messages.

    Raises:
        InputError: a window that is not a positive number, or commands in an empty window.
    """
    if isinstance(window_s, bool) or not isinstance(window_s, int | float) or not math.isfinite(window_s) \
            or window_s <= 0:
        raise InputError(f"run {name!r}: window_s = {window_s!r}; expected a duration > 0 s")
    cycles_w = float(window_s) / float(spec.tck_s)
    refi = float(spec.timings.get("REFI", 0) or 0)
    ranks = []
    for i, rank in enumerate(stats.ranks):
        if rank.cycles_total <= 0:
            if any(getattr(rank, f) > 0 for f in COUNT_FIELDS):
                raise InputError(f"run {name!r}: rank {i} has commands but cycles_total = 0")
            ranks.append(RankStats(cycles_total=cycles_w, cycles_pre=cycles_w,
                                   ref=cycles_w / refi if refi > 0 else 0.0))
            continue
        factor = cycles_w / rank.cycles_total
        changes: dict[str, float] = {f: getattr(rank, f) * factor for f in _STRETCHED}
        changes["ref"] = rank.ref * factor
        changes["cycles_total"] = cycles_w
        ranks.append(replace(rank, **changes))
    return CommandStats(ranks=tuple(ranks))


def model_columns(spec: Any, stats: CommandStats) -> tuple[np.ndarray, float]:
    """The energy model's columns (J per A, over ``CURRENT_NAMES``) and constant for ``stats``."""
    from hdeem_watch.dram.energy import energy_columns

    linear = energy_columns(spec, stats)
    return np.asarray(linear.columns, dtype=float), float(linear.constant_j)


def observation_from_run(spec: Any, model_stats: CommandStats, window_s: float, measured_j: float, *,
                         scale: float = 1.0, name: str = "run", time_ns: int = 0,
                         weight: float = 1.0) -> Observation:
    """A calibration row for one measured run.

    Args:
        spec: the memspec of one channel (datasheet currents, timings).
        model_stats: the modelled command statistics of the run (one channel).
        window_s: the measured window (s); residency and refresh are stretched to it.
        measured_j: the energy measured over the window (J, > 0).
        scale: how many such channels the measured energy covers (> 0).
        name: the run's name.
        time_ns: wall-clock time of the run's end (ns).
        weight: relative weight of the row.

    Raises:
        InputError: a bad energy, window or scale, naming the run.
    """
    measured = check_measured(name, measured_j)
    if isinstance(scale, bool) or not isinstance(scale, int | float) or not math.isfinite(scale) or scale <= 0:
        raise InputError(f"run {name!r}: scale = {scale!r}; expected a number > 0")
    stretched = stretch_stats(spec, model_stats, window_s, name=name)
    columns, constant = model_columns(spec, stretched)
    return Observation(name=name, columns=columns * scale, constant_j=constant * scale, measured_j=measured,
                       time_ns=int(time_ns), weight=weight, window_s=float(window_s))


def stats_window_s(spec: Any, stats: CommandStats) -> float:
    """The window of ``stats`` in seconds (longest rank window × tCK; NaN if empty)."""
    cycles = max((rank.cycles_total for rank in stats.ranks), default=0.0)
    return cycles * float(spec.tck_s) if cycles > 0 else math.nan
