"""Every event-table entry against its public source: Intel's perfmon files and the kernel's aliases."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hdeem_watch.counters.event_tables import PERFMON_COMMIT, ROLES, TABLES

FIXTURES = Path(__file__).resolve().parent / "fixtures"
PERFMON = FIXTURES / "perfmon"
PERF_JSON = FIXTURES / "perf"
INTEL = sorted(g for g, t in TABLES.items() if t.pmu_prefix == "uncore_imc")
AMD = sorted(g for g, t in TABLES.items() if t.pmu_prefix == "amd_umc")


def published(sources: tuple[str, ...]) -> dict[str, tuple[int, int, bool]]:
    """Event name → (code, umask, experimental) from the perfmon excerpts a table cites (AMD: the perf
    tool's memory-controller.json, umask = RdWrMask)."""
    events: dict[str, tuple[int, int, bool]] = {}
    for source in sources:
        if source.startswith("tools/perf/"):
            data = json.loads((PERF_JSON / Path(source).parent.name / Path(source).name).read_text())
            for event in data:
                events[event["EventName"]] = (int(event["EventCode"], 16), int(event.get("RdWrMask", "0"), 16), False)
            continue
        path, version = source.split(" ")
        data = json.loads((PERFMON / Path(path).name).read_text())
        assert data["source"].endswith(path) and PERFMON_COMMIT in data["source"]
        assert f"V{data['version']}".replace("VV", "V") == version
        for event in data["Events"]:
            events[event["EventName"]] = (int(event["EventCode"], 16), int(event["UMask"], 16),
                                          "experimental" in path)
    return events


@pytest.mark.parametrize("generation", sorted(TABLES))
def test_every_entry_is_published_exactly(generation):
    """Name, code, umask and the experimental flag of each entry equal the cited perfmon file's."""
    table = TABLES[generation]
    source = published(table.sources)
    assert table.events()
    for event in table.events():
        assert event.name in source, f"{generation}: {event.name} is not in {table.sources}"
        assert (event.event, event.umask, event.experimental) == source[event.name], event.name


@pytest.mark.parametrize("generation", INTEL)
def test_roles_are_known_and_core_roles_present(generation):
    """Every role is a documented one; CAS, ACT, PRE, power states and DRAM clock exist on every generation,
    refresh on all but Cascade Lake-SP (its files publish no DRAM_REFRESH event)."""
    table = TABLES[generation]
    assert set(table.roles) <= set(ROLES)
    for role in ("dclk", "cas_rd", "cas_wr", "act", "pre_page_miss", "pre_page_close", "ppd_cycles",
                 "sref_cycles"):
        assert table.events_of(role), f"{generation} lacks {role}"
    assert bool(table.events_of("refresh")) is (generation != "cascade-lake-sp")


@pytest.mark.parametrize("generation", AMD)
def test_amd_umc_roles(generation):
    """Zen 4/5: MEMCLK, CAS by read/write (RdWrMask 1/2), all ACTs and all PRECHARGEs, placed in rdwrmask; no
    refresh or power-state event is published, and the gaps say so."""
    table = TABLES[generation]
    assert set(table.roles) == {"dclk", "cas_rd", "cas_wr", "act", "pre_all"}
    assert [(e.name, e.event, e.umask, e.mask_field) for e in table.events()] == [
        ("umc_mem_clk", 0x00, 0, "rdwrmask"), ("umc_cas_cmd.rd", 0x0A, 1, "rdwrmask"),
        ("umc_cas_cmd.wr", 0x0A, 2, "rdwrmask"), ("umc_act_cmd.all", 0x05, 0, "rdwrmask"),
        ("umc_pchg_cmd.all", 0x06, 0, "rdwrmask")]
    assert table.memory == "DDR5" and not table.refresh_complete
    assert any(g.startswith("refresh") for g in table.gaps) and any("DRAM energy" in n for n in table.notes)


def test_sapphire_rapids_pseudo_channels_and_underfill_precharges():
    """SPR: CAS per pseudo-channel (PCH0 0x40, PCH1 0x80) and the underfill precharges 0x03/0x44, so that the
    counted precharges are PRE_COUNT.ALL = RD|WR|UFILL|PGT; dclk is 0x01/0x01, not perf's clockticks (0x01/0x00)."""
    table = TABLES["sapphire-rapids"]
    assert [(e.name, e.umask) for e in table.events_of("cas_pch0") + table.events_of("cas_pch1")] == [
        ("UNC_M_CAS_COUNT.PCH0", 0x40), ("UNC_M_CAS_COUNT.PCH1", 0x80)]
    precharges = [e for role in ("pre_page_miss", "pre_page_close", "pre_underfill") for e in table.events_of(role)]
    assert {e.event for e in precharges} == {0x03}
    umasks = [e.umask for e in precharges]
    assert sum(umasks) == 0xFF and all(a & b == 0 for i, a in enumerate(umasks) for b in umasks[i + 1:])
    assert published(table.sources)["UNC_M_PRE_COUNT.ALL"] == (0x03, 0xFF, False)
    ((dclk),) = table.events_of("dclk")
    assert (dclk.name, dclk.event, dclk.umask) == ("UNC_M_CLOCKTICKS", 0x01, 0x01)
    assert published(table.sources)["UNC_M_HCLOCKTICKS"] == (0x01, 0x00, False)


def test_autoprecharge_and_cke_gaps_follow_the_files():
    """RDA/WRA exist from Ice Lake-SP on; per-rank CKE residency only before it; refresh complete only on ICX."""
    for generation in ("haswell-ep", "broadwell-ep", "skylake-sp", "cascade-lake-sp"):
        assert not TABLES[generation].events_of("cas_rd_autopre")
        assert TABLES[generation].cke_ranks() == 8
    for generation in ("ice-lake-sp", "sapphire-rapids"):
        assert TABLES[generation].events_of("cas_wr_autopre")
        assert TABLES[generation].cke_ranks() == 0
    assert [g for g, t in TABLES.items() if t.refresh_complete] == ["ice-lake-sp"]


@pytest.mark.parametrize(("generation", "tree"), [("haswell-ep", "sysfs_haswell_ep"),
                                                  ("ice-lake-sp", "sysfs_ice_lake_sp")])
def test_cas_and_clock_agree_with_the_kernel_aliases(pmu_trees, generation, tree):
    """The kernel's own ``events/`` aliases (cas_count_read/write, clockticks) encode like our table."""
    events_dir = pmu_trees / tree / "bus/event_source/devices/uncore_imc_0/events"
    table = TABLES[generation]
    for alias, role in (("cas_count_read", "cas_rd"), ("cas_count_write", "cas_wr"), ("clockticks", "dclk")):
        fields = dict(part.split("=") for part in (events_dir / alias).read_text().strip().split(","))
        (event,) = table.events_of(role)
        assert (int(fields["event"], 16), int(fields["umask"], 16)) == (event.event, event.umask)


def test_ice_lake_page_misses_use_the_non_experimental_read_and_write_precharges():
    """icelakex_uncore.json publishes PRE_COUNT.RD (0x04) and .WR (0x08); the experimental PAGE_MISS is
    0x0c, exactly their two bits: the table counts page misses with the validated pair (issue 29)."""
    table = TABLES["ice-lake-sp"]
    source = published(table.sources)
    events = table.events_of("pre_page_miss")
    assert [e.name for e in events] == ["UNC_M_PRE_COUNT.RD", "UNC_M_PRE_COUNT.WR"]
    assert not any(e.experimental for e in events)
    code, umask, experimental = source["UNC_M_PRE_COUNT.PAGE_MISS"]
    assert experimental and code == events[0].event
    assert umask == events[0].umask | events[1].umask and events[0].umask & events[1].umask == 0


@pytest.mark.parametrize("generation", ["haswell-ep", "broadwell-ep", "skylake-sp", "cascade-lake-sp"])
def test_bypass_precharges_are_not_added_to_page_misses(generation):
    """HSX-CLX publish PRE_COUNT by cause (PAGE_MISS 0x01, PAGE_CLOSE 0x02) and by requester (RD 0x04,
    WR 0x08, BYP 0x10): two groupings of the same precharges, so BYP may overlap PAGE_MISS; the table
    uses the causes only and the gap says why."""
    table = TABLES[generation]
    source = published(table.sources)
    assert source["UNC_M_PRE_COUNT.BYP"][:2] == (0x02, 0x10)
    precharges = {e.name for role in ("pre_page_miss", "pre_page_close") for e in table.events_of(role)}
    assert precharges == {"UNC_M_PRE_COUNT.PAGE_MISS", "UNC_M_PRE_COUNT.PAGE_CLOSE"}
    assert any("BYP may overlap PAGE_MISS" in gap for gap in table.gaps)
