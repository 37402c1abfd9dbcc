"""The counters a real IMC would show for a channel's hidden command statistics (pure).

The simulated node knows its true per-rank :class:`~hdeem_watch.dram.stats.CommandStats`; this
module turns them into the per-event counts of one channel's ``uncore_imc`` PMU for a given
generation's :class:`~hdeem_watch.counters.event_tables.EventTable`, with the gaps of real hardware:

- activates, precharges, CASes and refreshes are **per channel** (summed over ranks);
- RD and RDA (WR and WRA) are one count where no auto-precharge umask is published;
- precharges are only the *explicit* ones (the auto-precharge of RDA/WRA is not a PRE command);
- refreshes are only the published causes: on tables without the opportunistic event the
  ``opportunistic_refresh_share`` of refreshes is invisible;
- CKE residency per rank only where ``POWER_CKE_CYCLES.RANK<n>`` is published, ``ppd_cycles`` is
  the time *all* ranks are in precharge power-down (taken as the minimum over ranks: the ranks of
  an idle channel power down together), and ``sref_cycles`` counts only self-refresh with a clock;
  without a clock (``1 − clocked_sref_share`` of self-refresh) ``dclk`` stops as well;
- on Sapphire Rapids the CASes also per DDR5 pseudo-channel (``cas_pch0``/``cas_pch1``: the
  ``pch0_share`` of them on pseudo-channel 0, as the node's address hash spreads lines), and the
  ``underfill_share`` of explicit precharges counted as ``pre_underfill`` instead of a page miss;
- counts are integers.

A role with several published events (Haswell-EP's ``ACT_COUNT.RD/.WR/.BYP``) gets its total split
over them (reads vs writes by CAS share; otherwise all on the first event): only their sum is used.

Example:
    >>> from hdeem_watch.counters.event_tables import TABLES
    >>> from hdeem_watch.dram.stats import RankStats
    >>> rank = RankStats(act=10, pre=10, rd=64, cycles_total=1000, cycles_act=200, cycles_pre=800)
    >>> counts = imc_event_counts(CommandStats(ranks=(rank, rank)), TABLES["haswell-ep"])
    >>> counts["UNC_M_CAS_COUNT.RD"], counts["UNC_M_DCLOCKTICKS"]
    (128, 1000)
"""

from __future__ import annotations

from collections.abc import Mapping

from hdeem_watch.counters.event_tables import MAX_CKE_RANKS, EventTable
from hdeem_watch.dram.stats import CommandStats

__all__ = ["imc_event_counts", "imc_role_counts", "role_counts_from_events"]


def imc_role_counts(stats: CommandStats, table: EventTable, *, clocked_sref_share: float = 1.0,
                    opportunistic_refresh_share: float = 0.0, page_close_share: float = 0.0,
                    pch0_share: float = 0.5, underfill_share: float = 0.0) -> dict[str, float]:
    """Role → count of one channel (before the split over a role's events).

    Args:
        stats: the channel's hidden per-rank statistics over the window.
        table: the generation (which roles exist, whether refresh is complete).
        clocked_sref_share: fraction of self-refresh during which the IMC keeps its clock.
        opportunistic_refresh_share: fraction of refreshes issued opportunistically (invisible where
            the table has no such event).
        page_close_share: fraction of explicit precharges caused by the page-close timer.
        pch0_share: fraction of the CASes on pseudo-channel 0 (tables with ``cas_pch0``/``cas_pch1``).
        underfill_share: fraction of the page-miss precharges for underfill reads (tables with
            ``pre_underfill``; elsewhere they stay page misses).
    """
    for name, share in (("clocked_sref_share", clocked_sref_share),
                        ("opportunistic_refresh_share", opportunistic_refresh_share),
                        ("page_close_share", page_close_share), ("pch0_share", pch0_share),
                        ("underfill_share", underfill_share)):
        if not 0.0 <= share <= 1.0:
            raise ValueError(f"{name} = {share}; expected a fraction in [0, 1]")
    ranks = stats.ranks
    total = ranks[0].cycles_total if ranks else 0.0
    sref = max((r.cycles_sref for r in ranks), default=0.0)
    rd, rda, wr, wra = (stats.total(c) for c in ("rd", "rda", "wr", "wra"))
    explicit = max(0.0, stats.total("pre") - (rda + wra))
    miss = explicit * (1.0 - page_close_share)
    underfill = miss * underfill_share if table.events_of("pre_underfill") else 0.0
    cas = rd + rda + wr + wra
    refresh = stats.total("ref")
    if not table.refresh_complete:
        refresh *= 1.0 - opportunistic_refresh_share
    roles = {
        "dclk": total - sref * (1.0 - clocked_sref_share),
        "cas_rd": rd + rda,
        "cas_wr": wr + wra,
        "cas_rd_autopre": rda,
        "cas_wr_autopre": wra,
        "act": stats.total("act"),
        "pre_page_miss": miss - underfill,
        "pre_underfill": underfill,
        "pre_page_close": explicit * page_close_share,
        "pre_all": explicit,  # AMD's umc_pchg_cmd.all: every PRECHARGE command (RDA/WRA send none)
        "refresh": refresh,
        "ppd_cycles": min((r.cycles_pdnp for r in ranks), default=0.0),
        "sref_cycles": sref * clocked_sref_share,
        "cas_pch0": cas * pch0_share,
        "cas_pch1": cas * (1.0 - pch0_share),
    }
    for n, rank in enumerate(ranks[:MAX_CKE_RANKS]):
        roles[f"cke_on_rank{n}"] = rank.cycles_act + rank.cycles_pre
    counted = table.roles
    return {role: value for role, value in roles.items() if counted.get(role)}


def _shares(role: str, n_events: int, read_share: float) -> list[float]:
    if n_events == 1:
        return [1.0]
    if role in ("act", "pre_page_miss"):
        return [read_share, 1.0 - read_share, *([0.0] * (n_events - 2))]
    return [1.0, *([0.0] * (n_events - 1))]


def imc_event_counts(stats: CommandStats, table: EventTable, **options: float) -> dict[str, int]:
    """Event name → integer count of one channel, as its PMU would report for the window.

    Args:
        stats: the channel's hidden statistics.
        table: the generation.
        **options: passed to :func:`imc_role_counts`.
    """
    roles = imc_role_counts(stats, table, **options)
    cas = roles.get("cas_rd", 0.0) + roles.get("cas_wr", 0.0)
    read_share = roles.get("cas_rd", 0.0) / cas if cas > 0 else 1.0
    counts: dict[str, int] = {}
    for role, total in roles.items():
        events = table.events_of(role)
        for event, share in zip(events, _shares(role, len(events), read_share)):
            counts[event.name] = counts.get(event.name, 0) + round(total * share)
    return counts


def role_counts_from_events(table: EventTable, event_counts: Mapping[str, float]) -> dict[str, float]:
    """Role → sum of its events' counts (the reader's side of the split above)."""
    nan = float("nan")
    return {role: float(sum([event_counts.get(e.name, nan) for e in events]))
            for role, events in table.roles.items() if events}

