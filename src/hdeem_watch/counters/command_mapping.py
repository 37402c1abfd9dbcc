"""Per-channel counter deltas of one window → the model's ``CommandStats`` (pure).

What each counter becomes (roles of :mod:`hdeem_watch.counters.event_tables`; ``T`` = the window
in DRAM clock cycles, from its wall-clock length and the memspec's tCK):

=====================  ===========================================================================
``RankStats`` field    from
=====================  ===========================================================================
``cycles_total``       ``T`` (wall clock, not ``dclk``: the IMC clock stops in package C3/C6).
``cycles_sref``        ``sref_cycles`` (clocked self-refresh) + ``T − dclk`` (unclocked time, during
                       which the DRAM must be in self-refresh), channel-wide, every rank.
``cycles_pdnp``        ``min(ppd_cycles, power-down of the rank)``: the channel-wide all-ranks-in-PPD
                       count is a lower bound of each rank's precharge power-down.
``cycles_pdna``        the rest of the rank's power-down, ``T − sref − cke_on_rank<n> − pdnp``.
``cycles_act``         ``min(CKE-on, ACT of the rank × open_cycles_per_act)`` — **estimated**: no
                       counter tells active from precharge standby; ``open_cycles_per_act`` (a bank
                       stays open this long per activate) is the caller's assumption.
``cycles_pre``         CKE-on cycles − ``cycles_act``.
``act``                ``act`` split over ranks by CKE-on share (the counters are per channel).
``rd``, ``wr``         ``cas_rd − rda``, ``cas_wr − wra``, split like ``act``.
``rda``, ``wra``       ``cas_rd_autopre``/``cas_wr_autopre`` where published (Ice Lake-SP and later);
                       otherwise 0 and the auto-precharges are charged as precharges (below): RD and
                       RDA draw the same IDD4R burst energy, so this is energy-neutral.
``pre``                explicit (``pre_page_miss + pre_page_close [+ pre_underfill]``, or AMD's
                       ``pre_all``) + implicit (``rda + wra`` when
                       known, else ``max(0, act − explicit)``: every opened row is closed once).
``ref``                ``refresh`` / ranks; where the published events miss some refresh causes
                       (:attr:`EventTable.refresh_complete` false) ``max(counted, nominal)`` with the
                       nominal one refresh per tREFI outside self-refresh, when tREFI is given.
``bank_active_cycles`` ``cycles_act`` (a lower bound; only the bank-wise ρ≠1 form uses it).
=====================  ===========================================================================

Generations without per-rank CKE counters (Ice Lake-SP, Sapphire Rapids) take every rank's
power-down as the channel-wide ``ppd_cycles`` (a lower bound) and count no active power-down.
Per-rank splits do not change the energy: the model is linear in the counts with the same currents
for every rank. Unknown is not zero: a window without a CAS or ACT count has no statistics
(:attr:`MappedChannel.stats` is ``None`` with a status).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from hdeem_watch.dram.stats import CommandStats, RankStats
from hdeem_watch.errors import InputError

STATUS_OK = "ok"
STATUS_NO_CLOCK = "no-clock"


@dataclass(frozen=True)
class MappedChannel:
    """The statistics of one channel over one window, and how they were obtained.

    Attributes:
        stats: per-rank statistics, or ``None`` when a required counter is unknown.
        status: ``"ok"``, ``"no-clock"`` (the IMC had no clock and issued nothing: an inactive
            channel, or self-refresh for the whole window) or ``"unknown: <why>"``.
        estimated: the fields that are estimates or bounds rather than counts, with why.
    """

    stats: CommandStats | None
    status: str
    estimated: tuple[str, ...]


def _value(counts: Mapping[str, float], role: str) -> float:
    value = counts.get(role, math.nan)
    return float(value) if value is not None else math.nan


def _known(value: float) -> bool:
    return math.isfinite(value)


def channel_stats(counts: Mapping[str, float], *, ranks: int, window_cycles: float,
                  open_cycles_per_act: float, refresh_complete: bool,
                  trefi_cycles: float | None = None) -> MappedChannel:
    """Map one channel's role deltas over a window to per-rank statistics.

    Args:
        counts: role → counted delta in the window (missing or NaN = not counted).
        ranks: ranks on the channel (from the memspec / node description).
        window_cycles: the window's wall-clock length in DRAM clock cycles.
        open_cycles_per_act: assumed cycles a bank stays open per activate (e.g. the memspec's tRAS
            for a closed-page policy, more for open pages); splits CKE-on time into active and
            precharge standby.
        refresh_complete: whether ``refresh`` counts every refresh (see the event table).
        trefi_cycles: the refresh interval tREFI in cycles, for the nominal refresh count.

    Returns:
        The mapped channel (statistics, status, what was estimated).
    """
    if ranks < 1 or not window_cycles > 0:
        raise ValueError(f"ranks = {ranks}, window_cycles = {window_cycles}: expected >= 1 and > 0")
    cas_rd, cas_wr, act = (_value(counts, r) for r in ("cas_rd", "cas_wr", "act"))
    missing = [r for r, v in (("cas_rd", cas_rd), ("cas_wr", cas_wr), ("act", act)) if not _known(v)]
    if missing:
        return MappedChannel(None, f"unknown: {', '.join(missing)} not counted in this window", ())
    total = float(window_cycles)
    estimated: list[str] = []
    dclk = _value(counts, "dclk")
    if not _known(dclk):
        dclk = total
        estimated.append("cycles_sref: dclk not counted; unclocked self-refresh unknown (taken as 0)")
    if dclk <= 0 and cas_rd + cas_wr + act <= 0:
        idle = RankStats(cycles_total=total, cycles_sref=total)
        return MappedChannel(CommandStats(ranks=(idle,) * ranks), STATUS_NO_CLOCK,
                             ("cycles_sref: no IMC clock in the window (inactive channel or self-refresh)",))
    sref_clocked = _value(counts, "sref_cycles")
    if not _known(sref_clocked):
        sref_clocked = 0.0
        estimated.append("cycles_sref: clocked self-refresh not counted (taken as 0)")
    sref = min(total, sref_clocked + max(0.0, total - dclk))
    awake = total - sref

    cke_on = [_value(counts, f"cke_on_rank{r}") for r in range(ranks)]
    ppd = _value(counts, "ppd_cycles")
    if all(_known(c) for c in cke_on):
        cke_on = [min(max(c, 0.0), awake) for c in cke_on]
    else:
        floor = min(max(ppd, 0.0), awake) if _known(ppd) else 0.0
        cke_on = [awake - floor] * ranks
        estimated.append("cycles_pdna/pdnp: no per-rank CKE counter; every rank's power-down = channel PPD "
                         "(lower bound)" if _known(ppd) else "cycles_pdna/pdnp: no CKE or PPD counter (taken as 0)")
    weight_sum = sum(cke_on)
    weights = [c / weight_sum for c in cke_on] if weight_sum > 0 else [1.0 / ranks] * ranks
    estimated.append("act/pre/rd/wr/rda/wra/ref per rank: channel counts split by CKE-on share")

    rda, wra, pre = _precharges(counts, act, estimated)

    refresh = _value(counts, "refresh")
    nominal = ranks * awake / trefi_cycles if trefi_cycles else math.nan
    if not refresh_complete or not _known(refresh):
        counted = refresh if _known(refresh) else 0.0
        refresh = max(counted, nominal) if _known(nominal) else counted
        estimated.append("ref: published refresh events miss some causes; max(counted, nominal 1/tREFI)"
                         if _known(nominal) else "ref: lower bound (published refresh events miss some causes)")

    rank_stats = []
    for r in range(ranks):
        w = weights[r]
        power_down = max(0.0, awake - cke_on[r])
        pdnp = min(max(ppd, 0.0), power_down) if _known(ppd) else 0.0
        act_cycles = min(cke_on[r], act * w * open_cycles_per_act)
        rank_stats.append(RankStats(
            act=act * w, pre=pre * w, rd=(cas_rd - rda) * w, wr=(cas_wr - wra) * w, rda=rda * w, wra=wra * w,
            ref=refresh / ranks, cycles_total=total, cycles_act=act_cycles, cycles_pre=cke_on[r] - act_cycles,
            cycles_pdna=power_down - pdnp, cycles_pdnp=pdnp, cycles_sref=sref, bank_active_cycles=act_cycles))
    estimated.append("cycles_act/cycles_pre: CKE-on time split by ACT × open_cycles_per_act (no counter)")
    return MappedChannel(CommandStats(ranks=tuple(rank_stats)), STATUS_OK, tuple(estimated))


def _precharges(counts: Mapping[str, float], act: float, estimated: list[str]) -> tuple[float, float, float]:
    """The window's auto-precharge reads, writes and all precharges (explicit + implicit) of :func:`channel_stats`.

    Args:
        counts: role → counted delta in the window (missing or NaN = not counted).
        act: the counted activates.
        estimated: what was estimated so far; a note is appended when RDA/WRA are not separable.

    Returns:
        ``(rda, wra, pre)``.
    """
    rda, wra = _value(counts, "cas_rd_autopre"), _value(counts, "cas_wr_autopre")
    explicit = _value(counts, "pre_page_miss") + _value(counts, "pre_page_close")
    if _known(underfill := _value(counts, "pre_underfill")):
        explicit += underfill
    if not _known(explicit):
        explicit = _value(counts, "pre_all")
    if _known(rda) and _known(wra):
        implicit = rda + wra
        explicit = explicit if _known(explicit) else max(0.0, act - implicit)
    else:
        rda = wra = 0.0
        explicit = explicit if _known(explicit) else act
        implicit = max(0.0, act - explicit)
        estimated.append("rda/wra: not separable (counted in rd/wr); their implicit precharges = act − explicit PRE")
    return rda, wra, explicit + implicit


def window_channels(counters: Mapping[str, Any]) -> tuple[Mapping[str, Mapping[str, Any]], float]:
    """(channel → role → delta, window in seconds) of a recorded window's ``counters``.

    Raises:
        InputError: no channels (with the record's ``status``), or a window that is not > 0 s.
    """
    channels = counters.get("channels")
    window_s = counters.get("window_s")
    if not isinstance(channels, Mapping) or not channels:
        raise InputError(f"counters: no channels ({counters.get('status', 'none recorded')})")
    if not isinstance(window_s, int | float) or not math.isfinite(window_s) or window_s <= 0:
        raise InputError(f"counters: window_s = {window_s!r}; expected a duration > 0")
    return channels, float(window_s)
