"""The simulated node's hidden DRAM commands, cumulative since open: what its memory controllers issue.

The sim's truth generator gives each run (:class:`~hdeem_watch.sim.model.RunPlan`) and
each opaque job (:class:`~hdeem_watch.sim.jobs.JobPlan`) per-DIMM statistics; between them
every DIMM is idle (precharge power-down, woken to refresh: :func:`~hdeem_watch.sim.power.idle_rank`).
:class:`HiddenCommands` adds them up over sim time, per DIMM and rank, as an array of the
:class:`~hdeem_watch.dram.stats.RankStats` fields — the ground truth from which the memory-controller
counters of the sim are made (``hdeem_watch.sim.imc_events``, in the daemon's counter source).

A kernel run's statistics accrue linearly over its traffic; a run stopped before its traffic ended
books the rest at the stop (as its energy is booked: the sim's ``owed`` energy). A job's phases accrue
phase by phase. Retired plans are folded into a settled total, so the totals never go back.

Example:
    >>> from hdeem_watch.dram.memspec import preset
    >>> hidden = HiddenCommands(preset("samsung-m393a1g43db0-cpb"), dimms=2, temps_c=[40.0, 40.0])
    >>> stats = hidden.at(1_000_000_000, [])
    >>> round(stats[0].ranks[0].cycles_total * 0.9375e-9, 6)   # 1 s of DDR4-2133 cycles
    1.0
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import fields
from typing import Any

import numpy as np

from hdeem_watch.dram.stats import CommandStats, RankStats
from hdeem_watch.sim.jobs import JobPlan
from hdeem_watch.sim.model import RunPlan
from hdeem_watch.sim.power import idle_rank

#: The RankStats fields, in array order.
FIELDS = tuple(f.name for f in fields(RankStats))


def stats_array(stats: CommandStats) -> np.ndarray:
    """``(ranks, fields)`` array of ``stats``."""
    return np.array([[getattr(rank, f) for f in FIELDS] for rank in stats.ranks], dtype=float)


def array_stats(values: np.ndarray) -> CommandStats:
    """:class:`CommandStats` of a ``(ranks, fields)`` array."""
    return CommandStats(ranks=tuple(RankStats(*row) for row in values.tolist()))  # fields in FIELDS order


def _plan_part(plan: RunPlan | JobPlan, t_ns: int, idle_per_s: np.ndarray) -> np.ndarray:
    """Per DIMM ``(ranks, fields)``: what ``plan`` adds at ``t_ns`` over the idle rate (its stats
    minus the idle statistics of the time it covered)."""
    out = np.zeros_like(idle_per_s)
    if isinstance(plan, JobPlan):
        seconds = plan.phase_seconds(t_ns)  # per phase
        for phase, s in zip(plan.phases, seconds, strict=True):
            if s <= 0:
                continue
            share = s / (phase.duration_ns * 1e-9)
            for d, dimm_stats in enumerate(phase.stats):
                out[d] += stats_array(dimm_stats) * share - idle_per_s[d] * s
        return out
    if plan.duration_ns <= 0 or not plan.stats:
        return out
    end = plan.traffic_end_ns
    covered_ns = min(max(t_ns, plan.t0_ns), end) - plan.t0_ns
    share = covered_ns / plan.duration_ns
    if plan.cpu_end_ns is not None and t_ns >= end:
        share = 1.0  # stopped: the rest of its traffic is booked at the stop, like its energy
    for d, busy in enumerate(plan.stats):
        if busy is not None:
            out[d] += stats_array(busy) * share - idle_per_s[d] * covered_ns * 1e-9
    return out


def plan_end_ns(plan: RunPlan | JobPlan) -> int:
    """When a plan's traffic and CPU load are both over (sim ns)."""
    return max(plan.traffic_end_ns, plan.cpu_end_ns or 0)


class HiddenCommands:
    """Cumulative hidden statistics of every DIMM since the sim opened.

    Args:
        spec: one DIMM's memspec.
        dimms: DIMMs on the node.
        temps_c: the DIMMs' temperatures (the idle refresh rate doubles above 85 °C).
    """

    def __init__(self, spec: Any, dimms: int, temps_c: Sequence[float] | np.ndarray) -> None:
        ranks = int(spec.nbr_of_ranks)
        self.idle_per_s = np.stack([stats_array(CommandStats(ranks=(idle_rank(spec, 1.0, float(temps_c[d])),) * ranks))
                                    for d in range(dimms)])
        self.settled = np.zeros_like(self.idle_per_s)

    def settle(self, plan: RunPlan | JobPlan) -> None:
        """Fold a finished plan (traffic and CPU load over) into the settled totals."""
        self.settled += _plan_part(plan, plan_end_ns(plan), self.idle_per_s)

    def unsettled_at(self, t_ns: int, plan: RunPlan | JobPlan) -> np.ndarray:
        """What a settled ``plan`` had not yet added at ``t_ns`` (its whole part minus its part then):
        subtract it from the totals to count at a time before the plan ended."""
        return _plan_part(plan, plan_end_ns(plan), self.idle_per_s) - _plan_part(plan, int(t_ns), self.idle_per_s)

    def array_at(self, t_ns: int, plans: Iterable[RunPlan | JobPlan]) -> np.ndarray:
        """``(dimms, ranks, fields)`` cumulative statistics at sim time ``t_ns``."""
        total = self.idle_per_s * (max(0, int(t_ns)) * 1e-9) + self.settled
        for plan in plans:
            total = total + _plan_part(plan, int(t_ns), self.idle_per_s)
        return total

    def at(self, t_ns: int, plans: Iterable[RunPlan | JobPlan]) -> list[CommandStats]:
        """Per DIMM, the cumulative statistics at sim time ``t_ns``."""
        return [array_stats(values) for values in self.array_at(t_ns, plans)]
