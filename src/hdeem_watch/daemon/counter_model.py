"""A window's counters → the model's per-channel ``CommandStats``, and the kernel-model cross-check (pure).

The run record's ``counters`` (:meth:`hdeem_watch.daemon.counter_windows.CounterWindows.finish`)
hold per channel the role deltas over the window. :func:`counter_groups` maps each channel with
:func:`~hdeem_watch.counters.command_mapping.channel_stats` (the window in DRAM cycles from the
counters' own span, tREFI and tRC from the memspec) into one group ``(stats, 1)`` per channel — the
form :func:`hdeem_watch.calibrate.rows.node_observation` sums into the node's calibration row. A
channel of ``k`` DIMMs (its ranks a multiple of the memspec's) is ``k`` groups of one DIMM each
(the split over ranks is energy-neutral). :func:`cross_check` puts the kernel model's node counts
beside the counted ones.

Example:
    >>> from hdeem_watch.dram.memspec import preset
    >>> spec = preset("samsung-m393a1g43db0-cpb")
    >>> counts = {"dclk": 1.0667e9, "cas_rd": 1e8, "cas_wr": 5e7, "act": 4e7, "pre_page_miss": 3e7,
    ...           "pre_page_close": 1e7, "refresh": 0.0, "cke_on_rank0": 1e9, "cke_on_rank1": 1e9,
    ...           "ppd_cycles": 0.0, "sref_cycles": 0.0}
    >>> groups, notes = counter_groups(spec, {"window_s": 1.0, "ranks": 2, "refresh_complete": False,
    ...                                      "channels": {"S0.imc0": counts}})
    >>> len(groups), round(groups[0][0].total("rd") / 1e8, 6)
    (1, 1.0)
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from hdeem_watch.counters.command_mapping import channel_stats
from hdeem_watch.dram.stats import CommandStats
from hdeem_watch.errors import InputError

#: The counts compared between the counters and the kernel model.
CHECKED = ("act", "rd", "wr")
#: Currents the counters make identifiable: they measure power-down residency (CKE, PPD), which no
#: kernel model knows, so the precharge and active power-down currents are fitted as well.
POWERDOWN_CURRENTS = ("idd2p", "idd3p")


def currents_with_counters(currents: Sequence[str]) -> tuple[str, ...]:
    """The currents to calibrate when counters describe every window: ``currents`` + :data:`POWERDOWN_CURRENTS`.

    >>> currents_with_counters(("idd0", "idd2n"))
    ('idd0', 'idd2n', 'idd2p', 'idd3p')
    """
    return tuple(dict.fromkeys((*currents, *POWERDOWN_CURRENTS)))


def counter_groups(spec: Any, counters: Mapping[str, Any]) -> tuple[list[tuple[CommandStats, int]], list[str]]:
    """Per channel (per DIMM of it) the window's statistics from its counters, and the estimates made.

    Args:
        spec: one DIMM's memspec.
        counters: the record's ``counters`` (``window_s``, ``ranks``, ``refresh_complete``, ``channels``).

    Raises:
        InputError: no usable counters (a window without a CAS or ACT count, a rank count the
            memspec cannot make up), naming the channel.
    """
    channels = counters.get("channels")
    window_s = counters.get("window_s")
    if not isinstance(channels, Mapping) or not channels:
        raise InputError(f"counters: no channels ({counters.get('status', 'none recorded')})")
    if not isinstance(window_s, int | float) or not math.isfinite(window_s) or window_s <= 0:
        raise InputError(f"counters: window_s = {window_s!r}; expected a duration > 0")
    ranks = int(counters.get("ranks") or spec.nbr_of_ranks)
    per_dimm = int(spec.nbr_of_ranks)
    if ranks % per_dimm:
        raise InputError(f"counters: {ranks} ranks per channel is not a whole number of "
                         f"{per_dimm}-rank DIMMs of {getattr(spec, 'memory_id', 'the memspec')}")
    dimms = ranks // per_dimm
    groups: list[tuple[CommandStats, int]] = []
    notes: set[str] = set()
    for name, counts in sorted(channels.items()):
        mapped = channel_stats({k: math.nan if v is None else float(v) for k, v in counts.items()},
                               ranks=ranks, window_cycles=float(window_s) / float(spec.tck_s),
                               open_cycles_per_act=float(spec.timings["RC"]),
                               refresh_complete=bool(counters.get("refresh_complete")),
                               trefi_cycles=float(spec.timings["REFI"]))
        if mapped.stats is None:
            raise InputError(f"counters: channel {name}: {mapped.status}")
        notes.update(mapped.estimated)
        for d in range(dimms):
            groups.append((CommandStats(ranks=mapped.stats.ranks[d * per_dimm:(d + 1) * per_dimm]), 1))
    return groups, sorted(notes)


def node_totals(groups: Sequence[tuple[CommandStats, int]]) -> dict[str, float]:
    """Node totals of ACT, PRE, RD (incl. RDA), WR (incl. WRA) and REF."""
    totals = {f: float(sum(stats.total(f) * n for stats, n in groups)) for f in ("act", "pre", "rd", "wr", "ref")}
    totals["rd"] += float(sum(stats.total("rda") * n for stats, n in groups))
    totals["wr"] += float(sum(stats.total("wra") * n for stats, n in groups))
    return totals


def cross_check(counted: Mapping[str, float], kernel: Mapping[str, float]) -> dict[str, Any]:
    """The kernel model's counts beside the counted ones, and counted / model per :data:`CHECKED` count.

    >>> cross_check({"act": 110.0, "rd": 100.0, "wr": 0.0}, {"act": 100.0, "rd": 100.0, "wr": 0.0})["ratio"]
    {'act': 1.1, 'rd': 1.0, 'wr': None}
    """
    ratio = {f: (counted[f] / kernel[f] if kernel.get(f) else None) for f in CHECKED if f in counted}
    return {"kernel_counts": dict(kernel), "counter_counts": dict(counted),
            "ratio": {f: (round(r, 6) if r is not None else None) for f, r in ratio.items()}}
