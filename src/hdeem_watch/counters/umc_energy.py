"""DRAM energy of a window from AMD's UMC counters and a DDR5 memspec (pure; no DRAM sensor needed).

AMD Zen 4/5 (EPYC 9004 Genoa, 9005 Turin) have no DRAM energy sensor, but each ``amd_umc_<n>`` PMU
counts the commands of one memory channel (perf's ``pmu-events/arch/x86/amdzen4/memory-controller.json``
and ``amdzen5/``: ``umc_act_cmd.all``, ``umc_cas_cmd.rd/.wr``, ``umc_pchg_cmd.all``, ``umc_mem_clk``;
the kernel's ``arch/x86/events/amd/uncore.c`` registers one PMU per active UMC). A DDR5 channel is two
independent 32-bit sub-channels, and a DRAMPower DDR5 memspec describes one of them, so a channel's
counts are split evenly over its two sub-channels (interleaved 64-byte lines: the split is exact for
CAS on streaming traffic, an estimate for ACT and PRE) and each becomes the statistics of one
sub-channel (:func:`hdeem_watch.counters.command_mapping.channel_stats`, the window from wall time and
tCK, tRC = tRAS + tRP, tREFI of the memspec's refresh mode), then joules with DRAMPower v6.2's DDR5
equations (:func:`hdeem_watch.dram.energy_ddr5.core_energy_ddr5`).

Which currents: the memspec's own. A memspec written by ``hdeem-watch calibrate --write-memspec`` on
a node that has DRAM sensors carries a ``calibration`` object beside its ``memspec``
(:func:`currents_basis`), so a node without sensors states whether its joules rest on datasheet
currents or on a calibration imported from such a node.

Example:
    >>> import json, pathlib
    >>> from hdeem_watch.dram.memspec_ddr5 import parse_memspec_ddr5
    >>> tree = json.loads((pathlib.Path(__file__).parents[3] / "examples" / "ddr5_drampower_test.json").read_text())
    >>> currents_basis(parse_memspec_ddr5(tree)).kind
    'datasheet'
    >>> tree["calibration"] = {"physical": True, "violations": [], "status": "ok", "n_runs": 12}
    >>> currents_basis(parse_memspec_ddr5(tree)).kind
    'calibrated'
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from hdeem_watch.counters.command_mapping import channel_stats, window_channels
from hdeem_watch.dram.energy import COMPONENT_KINDS
from hdeem_watch.dram.energy_ddr5 import COMPONENTS_DDR5, core_energy_ddr5
from hdeem_watch.dram.memspec_ddr5 import MemSpecDDR5
from hdeem_watch.dram.stats import CommandStats
from hdeem_watch.errors import InputError

#: Sub-channels per DDR5 channel (what one ``amd_umc`` PMU counts).
SUBCHANNELS = 2
#: Roles that are counts (split over the sub-channels); clocks and cycle counts are not.
_COUNT_ROLES = ("act", "cas_rd", "cas_wr", "pre_all", "pre_page_miss", "pre_page_close", "pre_underfill",
                "cas_rd_autopre", "cas_wr_autopre", "refresh")
#: The energy kinds of :data:`hdeem_watch.dram.energy.COMPONENT_KINDS`, with DDR5's same-bank refresh.
KINDS_DDR5: dict[str, tuple[str, ...]] = {**COMPONENT_KINDS, "refresh": ("ref_j", "refsb_j")}


@dataclass(frozen=True)
class CurrentsBasis:
    """Where a memspec's currents come from.

    Attributes:
        kind: ``"calibrated"`` (a memspec written by ``hdeem-watch calibrate --write-memspec``) or
            ``"datasheet"``.
        text: one line for the job record and the log.
    """

    kind: str
    text: str


def currents_basis(spec: Any, source: str | None = None) -> CurrentsBasis:
    """Whether ``spec``'s currents are a calibration (its file's ``calibration`` object) or a datasheet's.

    ``source``: the file or preset name, for the text (default: the memory id).
    """
    name = source or getattr(spec, "memory_id", "the memspec")
    raw = getattr(spec, "_raw", None) or {}
    calibration = raw.get("calibration") if isinstance(raw, Mapping) else None
    if isinstance(calibration, Mapping):
        runs = calibration.get("n_runs")
        status = calibration.get("status")
        detail = ", ".join(x for x in (f"{runs} runs" if runs is not None else "",
                                        f"status {status}" if status else "") if x)
        return CurrentsBasis("calibrated", f"calibrated currents imported from a node with DRAM sensors "
                                           f"({name}{'; ' + detail if detail else ''})")
    return CurrentsBasis("datasheet", f"datasheet currents of {name}")


def subchannel_groups(spec: MemSpecDDR5, counters: Mapping[str, Any]) -> tuple[list[tuple[CommandStats, int]], list[str]]:
    """Per channel, the statistics of one of its sub-channels (``(stats, 2)``: both alike) and the
    estimates made.

    Args:
        spec: the DDR5 memspec of one sub-channel.
        counters: a window's counters (``window_s``, ``ranks`` per channel, ``refresh_complete``,
            ``channels``: channel → role → counted delta).

    Raises:
        InputError: no channels, a bad window, or a channel without CAS or ACT counts (named).
    """
    channels, window_s = window_channels(counters)
    refi = spec.timings["REFI2" if spec.ref_mode == 2 else "REFI1"]
    groups: list[tuple[CommandStats, int]] = []
    notes = {"act/pre: a channel's counts split evenly over its two sub-channels"}
    for name, counts in sorted(channels.items()):
        shares = _pseudo_channel_shares(counts)
        if shares is not None:
            notes.add("cas_rd/cas_wr: split over the sub-channels by the pseudo-channels' CAS counts")
        for share in shares or (1.0 / SUBCHANNELS,):
            part = {role: (math.nan if value is None else float(value) * _share(role, share) if role in _COUNT_ROLES
                           else float(value)) for role, value in counts.items()}
            mapped = channel_stats(part, ranks=int(spec.nbr_of_ranks), window_cycles=float(window_s) / spec.tck_s,
                                   open_cycles_per_act=float(spec.timings["RAS"] + spec.timings["RP"]),
                                   refresh_complete=bool(counters.get("refresh_complete")),
                                   trefi_cycles=float(refi) if refi > 0 else None)
            if mapped.stats is None:
                raise InputError(f"counters: channel {name}: {mapped.status}")
            notes.update(mapped.estimated)
            groups.append((mapped.stats, 1 if shares is not None else SUBCHANNELS))
    return groups, sorted(notes)


def _pseudo_channel_shares(counts: Mapping[str, Any]) -> tuple[float, float] | None:
    """Each pseudo-channel's share of the channel's CASes where both are counted (Sapphire Rapids'
    ``CAS_COUNT.PCH0``/``.PCH1``: a DDR5 DIMM's two sub-channels), else None (an even split)."""
    values = [counts.get(f"cas_pch{p}") for p in range(SUBCHANNELS)]
    known = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    if len(known) != SUBCHANNELS or sum(known) <= 0:
        return None
    return known[0] / sum(known), known[1] / sum(known)


def _share(role: str, share: float) -> float:
    """A sub-channel's part of a counted role: its CAS share of CASes, half of the rest (ACT, PRE and
    refresh are counted per channel)."""
    return share if role.startswith("cas_") else 1.0 / SUBCHANNELS


def umc_energy(spec: MemSpecDDR5, counters: Mapping[str, Any], *, source: str | None = None) -> dict[str, Any]:
    """A window's DRAM energy by component from its UMC counts and ``spec``'s currents.

    Returns:
        ``{"source": "counters", "memspec", "currents": {"kind", "text"}, "window_s", "counts" (node
        ACT, PRE, RD, WR, REF), "components_j", "split_j" (:data:`KINDS_DDR5`), "total_j",
        "counter_estimates"}``.

    Raises:
        InputError: unusable counters (:func:`subchannel_groups`).
    """
    groups, notes = subchannel_groups(spec, counters)
    components = dict.fromkeys(COMPONENTS_DDR5, 0.0)
    counts = dict.fromkeys(("act", "pre", "rd", "wr", "ref"), 0.0)
    for stats, n in groups:
        energy = core_energy_ddr5(spec, stats)
        for name in COMPONENTS_DDR5:
            components[name] += n * energy.components[name]
        counts["act"] += n * stats.total("act")
        counts["pre"] += n * stats.total("pre")
        counts["rd"] += n * (stats.total("rd") + stats.total("rda"))
        counts["wr"] += n * (stats.total("wr") + stats.total("wra"))
        counts["ref"] += n * stats.total("ref")
    basis = currents_basis(spec, source)
    return {"source": "counters", "memspec": spec.memory_id, "currents": {"kind": basis.kind, "text": basis.text},
            "window_s": float(counters["window_s"]), "counts": counts, "components_j": components,
            "split_j": {kind: float(sum(components[c] for c in parts)) for kind, parts in KINDS_DDR5.items()},
            "total_j": float(sum(components.values())), "counter_estimates": notes}


def job_model_ddr5(spec: MemSpecDDR5, counters: Mapping[str, Any], *, source: str | None = None) -> dict[str, Any]:
    """:func:`umc_energy` in the shape of a job record's ``model``
    (:func:`hdeem_watch.calibrate.counter_model.counters_model`): the memspec's joules under
    ``datasheet`` or ``calibrated`` as :func:`currents_basis` says (the other is None; a node
    without a DRAM sensor has no fit of its own), ``currents`` saying which.
    """
    energy = umc_energy(spec, counters, source=source)
    kind = energy["currents"]["kind"]
    other = "datasheet" if kind == "calibrated" else "calibrated"
    return {
        "source": "counters", "memspec": energy["memspec"], "window_s": energy["window_s"],
        "counts": energy["counts"], "counter_estimates": energy["counter_estimates"],
        "components_j": {kind: energy["components_j"], other: None},
        "split_j": {kind: energy["split_j"], other: None},
        f"{kind}_j": energy["total_j"], f"{other}_j": None, "intercept_j": None,
        "currents": energy["currents"], "sensors": {},
    }
