"""From a measured run to a calibration row (DESIGN.md §4).

The command counts (ACT, PRE, RD, WR, ... per rank) come from the model of the run (a command trace,
or the model of the announced kernel); the background residency is the model's fraction of each
state times the *measured* window, and refresh is stretched to the measured window too (the device
refreshes whatever the kernel does). An idle run is command statistics with no commands; if even
its window is empty (``cycles_total == 0``) the rank is taken as precharged standby for the whole
window with a refresh every ``REFI`` (both done by :func:`hdeem_watch.dram.stats.stretch_stats`).
``scale`` multiplies the row (e.g. the number of identical channels or DIMMs the measured energy
covers).

The energy model's linear decomposition turns the stretched statistics into one column per current
(:func:`hdeem_watch.dram.energy.energy_columns` over ``CURRENT_NAMES`` for a DDR4 memspec,
:func:`hdeem_watch.dram.energy_ddr5.energy_columns_ddr5` over ``CURRENT_NAMES_DDR5`` for a DDR5 one:
:func:`hdeem_watch.dram.linear.linear_energy` dispatches on the memspec's type); the fit later moves the currents it does not
calibrate into the constant.

:func:`node_observation` sums the rows of a node's channel groups (:mod:`hdeem_watch.dram.node`)
into ONE row against the node's total measured DRAM energy.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from hdeem_watch.calibrate.observation import Observation, check_measured
from hdeem_watch.dram.linear import linear_energy
from hdeem_watch.dram.memspec import MemSpec
from hdeem_watch.dram.memspec_ddr5 import MemSpecDDR5
from hdeem_watch.dram.stats import CommandStats, RankStats, stretch_stats
from hdeem_watch.errors import InputError

#: The energy components that scale with the activation count (the ACT and its PRE).
ACT_COMPONENTS = ("act_j", "pre_j")


def model_columns(spec: MemSpec | MemSpecDDR5, stats: CommandStats) -> tuple[np.ndarray, float]:
    """The energy model's columns (J per A, over the spec's current names) and constant for ``stats``."""
    linear = linear_energy(spec, stats)
    return np.asarray(linear.columns, dtype=float), float(linear.constant_j)


def act_columns(spec: MemSpec | MemSpecDDR5, stats: CommandStats) -> np.ndarray:
    """The part of ``model_columns(spec, stats)`` that the activations and precharges carry."""
    linear = linear_energy(spec, stats)
    return np.sum([np.asarray(linear.component_columns[c], dtype=float) for c in ACT_COMPONENTS], axis=0)


def observation_from_run(spec: MemSpec | MemSpecDDR5, model_stats: CommandStats, window_s: float, measured_j: float, *,
                         scale: float = 1.0, name: str = "run", time_ns: int = 0,
                         weight: float = 1.0, traffic_s: float | None = None, commands: str = "") -> Observation:
    """A calibration row for one measured run.

    Args:
        spec: the memspec of one channel (datasheet currents, timings), DDR4 or DDR5.
        model_stats: the modelled command statistics of the run (one channel).
        window_s: the measured window (s); residency and refresh are stretched to it.
        measured_j: the energy measured over the window (J, > 0).
        scale: how many such channels the measured energy covers (> 0).
        name: the run's name.
        time_ns: wall-clock time of the run's end (ns).
        weight: relative weight of the row.
        traffic_s: how long the run's traffic lasted, when known (a run's announced
            ``metadata.modelled_s``): a longer window is the run's statistics stretched to
            ``traffic_s``, then precharged standby (with refresh) for the rest — not the run's
            state mix stretched over all of it. For windows that end well after the traffic (the
            demo's at high speed end at the daemon's first poll after the stop, up to seconds of
            sim time later). None or a longer traffic: stretched to the window as always.
        commands: where ``model_stats``' commands come from (``"counters"``, ``"model"``; see
            :class:`Observation`); a ``"model"`` row keeps its activations' columns.

    Raises:
        InputError: a bad energy, window or scale, naming the run.
    """
    measured = check_measured(name, measured_j)
    if isinstance(scale, bool) or not isinstance(scale, int | float) or not math.isfinite(scale) or scale <= 0:
        raise InputError(f"run {name!r}: scale = {scale!r}; expected a number > 0")
    own_s = traffic_s if traffic_s is not None and math.isfinite(traffic_s) and traffic_s > 0 else math.nan
    if math.isfinite(own_s) and isinstance(window_s, int | float) and window_s > own_s:
        busy = stretch_stats(spec, model_stats, own_s, name=name)
        columns, constant = model_columns(spec, busy)
        idle = CommandStats(ranks=tuple(RankStats() for _ in model_stats.ranks))
        idle_columns, idle_constant = model_columns(spec, stretch_stats(spec, idle, float(window_s) - own_s, name=name))
        columns, constant = columns + idle_columns, constant + idle_constant
    else:
        busy = stretch_stats(spec, model_stats, window_s, name=name)
        columns, constant = model_columns(spec, busy)
    act = act_columns(spec, busy) * scale if commands == "model" else None
    return Observation(name=name, columns=columns * scale, constant_j=constant * scale, measured_j=measured,
                       time_ns=int(time_ns), weight=weight, window_s=float(window_s), commands=commands,
                       act_columns=act)


def stats_window_s(spec: MemSpec | MemSpecDDR5, stats: CommandStats) -> float:
    """The window of ``stats`` in seconds (longest rank window × tCK; NaN if empty)."""
    cycles = max((rank.cycles_total for rank in stats.ranks), default=0.0)
    return cycles * float(spec.tck_s) if cycles > 0 else math.nan


def node_observation(spec: MemSpec | MemSpecDDR5, groups: Sequence[tuple[CommandStats, int]], window_s: float,
                     measured_j: float, *, name: str = "run", time_ns: int = 0,
                     weight: float = 1.0, traffic_s: float | None = None, commands: str = "",
                     act_factors: Sequence[float] = ()) -> Observation:
    """ONE calibration row for a node: its channel groups' rows over the same window, summed.

    Each group's row is ``observation_from_run(spec, stats, window_s, measured_j, scale=channels,
    traffic_s=traffic_s)``
    (``groups`` as :func:`hdeem_watch.dram.node.node_run_stats` returns them); the node row's columns
    and constant are their sums, against the node's measured energy.

    Raises:
        InputError: no groups, or a bad window or energy (naming the run).
    """
    if not groups:
        raise InputError(f"run {name!r}: no channel groups")
    rows = [observation_from_run(spec, stats, window_s, measured_j, scale=float(n), name=name, time_ns=time_ns,
                                 weight=weight, traffic_s=traffic_s, commands=commands) for stats, n in groups]
    columns = np.sum([row.columns for row in rows], axis=0)
    constant = float(sum(row.constant_j for row in rows))
    act = None if commands != "model" else np.sum([row.act_columns for row in rows if row.act_columns is not None],
                                                   axis=0)
    return Observation(name=rows[0].name, columns=columns, constant_j=constant, measured_j=rows[0].measured_j,
                       time_ns=rows[0].time_ns, weight=rows[0].weight, window_s=rows[0].window_s,
                       commands=commands, act_columns=act, act_factors=tuple(act_factors) if act is not None else ())
