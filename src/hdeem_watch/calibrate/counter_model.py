"""A window's counters → the model's per-channel ``CommandStats``, and the kernel-model cross-check (pure).

The run record's ``counters`` (:meth:`hdeem_watch.daemon.counters.windows.CounterWindows.finish`)
hold per channel the role deltas over the window. :func:`counter_groups` maps each channel with
:func:`~hdeem_watch.counters.command_mapping.channel_stats` (the window in DRAM cycles from the
counters' own span, tREFI and tRC from the memspec) into one group ``(stats, 1)`` per channel — the
form :func:`hdeem_watch.calibrate.rows.node_observation` sums into the node's calibration row. A
channel of ``k`` DIMMs (its ranks a multiple of the memspec's) is ``k`` groups of one DIMM each
(the split over ranks is energy-neutral). :func:`cross_check` puts the kernel model's node counts
beside the counted ones. For a SLURM job (:mod:`hdeem_watch.daemon.jobs.records`),
:func:`sum_counters` adds its segments' counts and :func:`counters_model` models the energy by
component from them alone, with the datasheet and the calibrated currents.

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

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from hdeem_watch.counters.command_mapping import channel_stats, window_channels
from hdeem_watch.counters.umc_energy import job_model_ddr5, subchannel_groups
from hdeem_watch.dram.energy import COMPONENT_KINDS, component_energy
from hdeem_watch.dram.memspec_ddr5 import MemSpecDDR5
from hdeem_watch.dram.node import node_counts
from hdeem_watch.dram.stats import CommandStats
from hdeem_watch.errors import InputError

#: How counted windows split awake time into active and precharged standby (:func:`open_page_split`).
OPEN_PAGE_NOTE = ("cycles_act/cycles_pre: open-page estimate (no counter): a rank with activations keeps rows "
                  "open while its clock is on, minus tRP per refresh; without activations it is precharged")
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
    if isinstance(spec, MemSpecDDR5):  # a channel's counts are its two sub-channels' (pseudo-channels on SPR)
        sub_groups, sub_notes = subchannel_groups(spec, counters)
        return ([(open_page_split(spec, stats), n) for stats, n in sub_groups],
                sorted({*(n for n in sub_notes if not n.startswith("cycles_act/cycles_pre")), OPEN_PAGE_NOTE}))
    channels, window_s = window_channels(counters)
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
        notes.update(n for n in mapped.estimated if not n.startswith("cycles_act/cycles_pre"))
        notes.add(OPEN_PAGE_NOTE)
        stats = open_page_split(spec, mapped.stats)
        for d in range(dimms):
            groups.append((CommandStats(ranks=stats.ranks[d * per_dimm:(d + 1) * per_dimm]), 1))
    return groups, sorted(notes)


def open_page_split(spec: Any, stats: CommandStats) -> CommandStats:
    """Active vs precharged standby of counted statistics under an open-page controller (pure).

    No IMC counter tells active from precharged standby. An open-page controller with power-down
    (Haswell-EP's default, and the simulated node's) leaves a row open after its last access and
    puts an idle rank into power-down: a rank that activated rows in the window has them open
    whenever its clock is on, except the ``tRP`` before each refresh. A rank without activations in
    the window was precharged while awake (its refreshes' ``tRFC`` count as active, as DRAMPower
    books them). So per rank: ``cycles_act = CKE-on − REF·tRP`` when ``act > 0``, else
    ``min(CKE-on, REF·tRFC)``; ``cycles_pre`` the rest of CKE-on. The earlier ``ACT × tRC`` (a
    closed-page bound) undercounted a streaming kernel's open rows many times (CAS per ACT 4–60).

    >>> from hdeem_watch.dram.memspec import preset
    >>> from hdeem_watch.dram.stats import RankStats
    >>> spec = preset("samsung-m393a1g43db0-cpb")
    >>> busy = RankStats(act=10, rd=400, ref=2, cycles_total=1e4, cycles_act=10 * 50, cycles_pre=8000 - 500,
    ...                  cycles_pdna=2000)
    >>> rank = open_page_split(spec, CommandStats(ranks=(busy,))).ranks[0]
    >>> rank.cycles_act + rank.cycles_pre, rank.cycles_pre == 2 * spec.timings["RP"]
    (8000.0, True)
    """
    trp, trfc = float(spec.timings["RP"]), float(spec.trfc)
    ranks = []
    for rank in stats.ranks:
        awake = rank.cycles_act + rank.cycles_pre
        if rank.act > 0:
            active = max(0.0, awake - rank.ref * trp)
        else:
            active = min(awake, rank.ref * trfc)
        ranks.append(dataclasses.replace(rank, cycles_act=active, cycles_pre=awake - active, bank_active_cycles=active))
    return CommandStats(ranks=tuple(ranks))


def node_totals(groups: Sequence[tuple[CommandStats, int]]) -> dict[str, float]:
    """Node totals of ACT, PRE, RD (incl. RDA), WR (incl. WRA) and REF."""
    totals = node_counts(groups)
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


def sum_counters(windows: Sequence[Mapping[str, Any] | None]) -> dict[str, Any] | None:
    """The counters of several windows of one job (its segments) as one: per channel and role the
    counts summed, ``window_s`` summed; a role missing in a counted window is unknown (NaN).

    Windows without counters (None, or no channels) are left out and the ``status`` says how many;
    None when no window has counters.

    >>> a = {"source": "sim", "window_s": 1.0, "ranks": 2, "channels": {"c0": {"act": 1.0, "cas_rd": 2.0}}}
    >>> b = {"source": "sim", "window_s": 2.0, "ranks": 2, "channels": {"c0": {"act": 3.0}}}
    >>> total = sum_counters([a, None, b])
    >>> total["window_s"], total["channels"]["c0"]["act"], total["status"]
    (3.0, 4.0, 'partial: 2 of 3 segments counted')
    >>> math.isnan(total["channels"]["c0"]["cas_rd"])
    True
    """
    counted = [w for w in windows if isinstance(w, Mapping) and isinstance(w.get("channels"), Mapping)
               and w.get("channels")]
    if not counted:
        return None
    channels: dict[str, dict[str, float]] = {}
    names = list(dict.fromkeys(c for w in counted for c in w["channels"]))
    for channel in names:
        roles = list(dict.fromkeys(r for w in counted for r in (w["channels"].get(channel) or {})))
        channels[channel] = {}
        for role in roles:
            values = [(w["channels"].get(channel) or {}).get(role) for w in counted]
            known = [float(v) for v in values if v is not None]
            channels[channel][role] = float(sum(known)) if len(known) == len(values) else math.nan
    statuses = sorted({str(w.get("status", "ok")) for w in counted} - {"ok"})
    status = "ok" if len(counted) == len(windows) else f"partial: {len(counted)} of {len(windows)} segments counted"
    if statuses:
        status = "; ".join([status, *statuses]) if status != "ok" else "; ".join(statuses)
    first = counted[0]
    return {"source": first.get("source"), "generation": first.get("generation"), "status": status,
            "ranks": first.get("ranks"), "refresh_complete": first.get("refresh_complete"),
            "window_s": float(sum(float(w.get("window_s") or 0.0) for w in counted)),
            "segments_counted": len(counted), "sensors": dict(first.get("sensors") or {}), "channels": channels}


def _split(components: Mapping[str, float]) -> dict[str, float]:
    return {kind: float(sum(components[c] for c in parts)) for kind, parts in COMPONENT_KINDS.items()}


def counters_model(spec: Any, counters: Mapping[str, Any], *, datasheet_a: np.ndarray,
                   calibrated_a: np.ndarray | None, intercept_j: float = 0.0,
                   measured_j: Mapping[str, float] | None = None) -> dict[str, Any]:
    """A window's modelled DRAM energy by component from its counters alone (``model.source = "counters"``).

    A DDR5 memspec (AMD Zen 4/5's UMC counters, no DRAM sensor) is modelled by
    :func:`hdeem_watch.counters.umc_energy.job_model_ddr5` with the memspec's own currents.

    Args:
        spec: one DIMM's memspec.
        counters: the window's counters (:func:`sum_counters` of a job's segments).
        datasheet_a: the memspec's currents.
        calibrated_a: the current calibration's currents (None: no fit yet).
        intercept_j: the fit's intercept (node-wide, not split by component or sensor).
        measured_j: measured energy per sensor over the window, for the per-sensor split.

    Returns:
        ``{"source", "memspec", "window_s", "counts", "counter_estimates", "components_j":
        {"datasheet", "calibrated"}, "split_j": {"datasheet", "calibrated"} (:data:`COMPONENT_KINDS`),
        "datasheet_j", "calibrated_j", "intercept_j", "sensors"}``; the calibrated entries are None
        without a fit. ``sensors`` (sensor → datasheet/calibrated/measured J) when the counter
        channels name their sensors.

    Raises:
        InputError: unusable counters (see :func:`counter_groups`).
    """
    if isinstance(spec, MemSpecDDR5):  # AMD Zen 4/5: the UMC counts and the memspec's own currents
        return job_model_ddr5(spec, counters)
    groups, notes = counter_groups(spec, counters)
    window_s = float(counters["window_s"])
    datasheet = component_energy(spec, groups, window_s, datasheet_a)
    calibrated = None if calibrated_a is None else component_energy(spec, groups, window_s, calibrated_a)
    model: dict[str, Any] = {
        "source": "counters", "memspec": getattr(spec, "memory_id", None), "window_s": window_s,
        "counts": node_totals(groups), "counter_estimates": notes,
        "components_j": {"datasheet": datasheet, "calibrated": calibrated},
        "split_j": {"datasheet": _split(datasheet), "calibrated": None if calibrated is None else _split(calibrated)},
        "datasheet_j": float(sum(datasheet.values())),
        "calibrated_j": None if calibrated is None else float(sum(calibrated.values())) + float(intercept_j),
        "intercept_j": None if calibrated is None else float(intercept_j),
    }
    sensors = counters.get("sensors") or {}
    per_sensor: dict[str, dict[str, Any]] = {}
    for channel, counts in sorted((counters.get("channels") or {}).items()):
        sensor = sensors.get(channel)
        if not sensor:
            continue
        own, _ = counter_groups(spec, {**counters, "channels": {channel: counts}})
        entry = per_sensor.setdefault(str(sensor), {"channels": [], "datasheet_j": 0.0,
                                                    "calibrated_j": None if calibrated_a is None else 0.0})
        entry["channels"].append(channel)
        entry["datasheet_j"] += float(sum(component_energy(spec, own, window_s, datasheet_a).values()))
        if calibrated_a is not None:
            entry["calibrated_j"] += float(sum(component_energy(spec, own, window_s, calibrated_a).values()))
    for sensor, entry in per_sensor.items():
        value = (measured_j or {}).get(sensor)
        entry["measured_j"] = float(value) if isinstance(value, int | float) and math.isfinite(value) else None
    model["sensors"] = per_sensor
    return model
