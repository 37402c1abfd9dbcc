"""The sim's IMC counts on Sapphire Rapids: CAS per pseudo-channel and underfill precharges (issue 30)."""

from __future__ import annotations

import pytest

from hdeem_watch.counters.command_mapping import channel_stats
from hdeem_watch.counters.event_tables import TABLES
from hdeem_watch.dram.stats import CommandStats, RankStats
from hdeem_watch.sim.imc_events import imc_event_counts, imc_role_counts, role_counts_from_events

RANK = RankStats(act=400, pre=400, rd=3000, wr=1000, rda=200, ref=8, cycles_total=100_000, cycles_act=60_000,
                 cycles_pre=40_000)


def test_spr_counts_split_cas_by_pseudo_channel_and_precharges_by_cause() -> None:
    """PCH0 + PCH1 = every CAS with the given share on PCH0; UFILL + RD + WR + PGT = the explicit
    precharges; the mapping back gives the hidden commands."""
    stats = CommandStats(ranks=(RANK,))
    counts = imc_event_counts(stats, TABLES["sapphire-rapids"], pch0_share=0.6, underfill_share=0.25,
                              page_close_share=0.1)
    assert counts["UNC_M_CAS_COUNT.PCH0"] + counts["UNC_M_CAS_COUNT.PCH1"] == 4200
    assert counts["UNC_M_CAS_COUNT.PCH0"] == round(0.6 * 4200)
    explicit = 400 - 200  # the RDAs' precharges are implicit
    assert counts["UNC_M_PRE_COUNT.UFILL"] == round(explicit * 0.9 * 0.25)
    pre = sum(counts[f"UNC_M_PRE_COUNT.{u}"] for u in ("RD", "WR", "PGT", "UFILL"))
    assert pre == pytest.approx(explicit, abs=2)
    roles = role_counts_from_events(TABLES["sapphire-rapids"], counts)
    mapped = channel_stats(roles, ranks=1, window_cycles=100_000, open_cycles_per_act=40,
                           refresh_complete=False).stats
    assert mapped is not None
    assert mapped.total("pre") == pytest.approx(400, abs=2) and mapped.total("rd") + mapped.total("rda") == 3200


def test_tables_without_pseudo_channels_are_unchanged() -> None:
    """Haswell-EP has no PCH or UFILL events: the underfill share stays a page miss, nothing new appears."""
    roles = imc_role_counts(CommandStats(ranks=(RANK,)), TABLES["haswell-ep"], underfill_share=0.5)
    assert "cas_pch0" not in roles and "pre_underfill" not in roles
    assert roles["pre_page_miss"] == pytest.approx(200)
    with pytest.raises(ValueError, match="pch0_share"):
        imc_role_counts(CommandStats(ranks=(RANK,)), TABLES["sapphire-rapids"], pch0_share=1.5)
