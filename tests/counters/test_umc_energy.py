"""AMD Zen 4 without a DRAM sensor (issue 30): a job's DRAM energy from the amd_umc counts.

The whole path on the Genoa fixture host (tests/counters/pmu_trees.py ``genoa``: 24 ``amd_umc_<n>``
PMUs as ``arch/x86/events/amd/uncore.c`` registers them, format ``event`` config:0-7 and
``rdwrmask`` config:8-9; the events of perf's ``pmu-events/arch/x86/amdzen4/memory-controller.json``):
plan → open every UMC event → two reads of the fake reader → role deltas → sub-channel statistics →
DDR5 energy, judged against the hidden truth the counts came from (a DDR5 kernel's statistics).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from hdeem_watch.counters.host_plan import plan_host
from hdeem_watch.counters.permissions import check_access
from hdeem_watch.counters.reader import FakeCounterReader
from hdeem_watch.counters.session import CounterSession
from hdeem_watch.counters.umc_energy import SUBCHANNELS, currents_basis, umc_energy
from hdeem_watch.dram.ddr5_channel import kernel_stats_ddr5
from hdeem_watch.dram.energy_ddr5 import core_energy_ddr5
from hdeem_watch.dram.memspec_ddr5 import MemSpecDDR5, parse_memspec_ddr5
from hdeem_watch.errors import InputError
from hdeem_watch.sim.imc_events import imc_event_counts

ROOT = Path(__file__).resolve().parents[2]
FIXTURES = Path(__file__).resolve().parent / "fixtures"
TWO_RANK = ROOT / "tests" / "data" / "drampower_ddr5" / "memspecs" / "ddr5_2r_allterms.json"
#: JESD79-5 DDR5-4800B timings of a 32-bit BL16 sub-channel (as tests/dram/test_ddr5_stats.py).
DDR5_4800 = {"tCK": 1 / 2.4e9, "RL": 40, "WL": 38, "RCD": 40, "RP": 40, "RAS": 77, "RTP": 18, "WR": 72,
             "CCD_S_slr": 8, "CCD_L_slr": 12, "CCD_L_WR_slr": 48, "WTR_S": 6, "WTR_L": 24, "RRD_S_slr": 8,
             "RRD_L_slr": 12, "FAW_slr": 32, "REFI1": 9360, "REFI2": 4680, "RFC1_slr": 708, "RFC2_slr": 384,
             "RFCsb_slr": 312, "RTRS": 2}


def genoa_spec(calibration: dict[str, object] | None = None) -> MemSpecDDR5:
    """DRAMPower's 2-rank DDR5 test memspec as a BL16 32-bit sub-channel with DDR5-4800 timings."""
    tree = json.loads(TWO_RANK.read_text())
    tree["memspec"]["memarchitecturespec"].update(burstLength=16, maxBurstLength=16, width=8, nbrOfDevices=4,
                                                  nbrOfBankGroups=8, nbrOfBanks=32, RefMode=1)
    tree["memspec"]["memtimingspec"].update(DDR5_4800)
    if calibration is not None:
        tree["calibration"] = calibration
    return parse_memspec_ddr5(tree, where=str(TWO_RANK))


class Clock:
    def __init__(self) -> None:
        self.t = 1_000_000

    def __call__(self) -> int:
        return self.t


def counted_window(pmu_trees: Path, spec: MemSpecDDR5) -> tuple[dict[str, object], object, int]:
    """One window of the Genoa host whose channels all carry a triad's traffic: (counters, the
    truth of one sub-channel, channels)."""
    plan = plan_host(pmu_trees / "sysfs_genoa", cpuinfo_text=(FIXTURES / "cpuinfo" / "genoa").read_text(),
                     access=check_access(paranoid=0, capabilities=0), ranks=spec.nbr_of_ranks)
    assert plan.table.generation == "zen4" and len(plan.channels) == 24
    sub = kernel_stats_ddr5(spec, "triad", 2_000_000, 8).stats  # one sub-channel's truth
    window_ns = round(sub.ranks[0].cycles_total * spec.tck_s * 1e9)
    per_channel = imc_event_counts(sub.scaled(SUBCHANNELS), plan.table)
    names = {e.config: e.name for e in plan.events}

    def truth(pmu_type: int, config: int, cpu: int, elapsed_ns: int) -> int:
        return per_channel[names[config]] * elapsed_ns // window_ns

    clock = Clock()
    reader = FakeCounterReader(truth, clock=clock, known_types=frozenset(c.pmu_type for c in plan.channels))
    session = CounterSession(reader, plan.channels, plan.events).open()
    before = session.read()
    clock.t += window_ns
    deltas = session.role_deltas(before, session.read())
    session.close()
    counters = {"source": "perf", "generation": plan.table.generation, "window_s": window_ns / 1e9,
                "ranks": spec.nbr_of_ranks, "refresh_complete": plan.table.refresh_complete, "channels": deltas}
    return counters, sub, len(plan.channels)


def test_umc_counts_give_the_truths_commands_and_their_energy(pmu_trees: Path) -> None:
    """ACT, RD, WR come back exactly; their energies (and precharge, refresh) equal the truth's."""
    spec = genoa_spec()
    counters, sub, channels = counted_window(pmu_trees, spec)
    model = umc_energy(spec, counters)
    n = channels * SUBCHANNELS
    for field, role in (("act", "act"), ("rd", "rd"), ("wr", "wr")):
        truth = n * (sub.total(role) + (sub.total(f"{role}a") if role in ("rd", "wr") else 0.0))
        assert model["counts"][field] == pytest.approx(truth, rel=1e-6)
    truth_j = core_energy_ddr5(spec, sub).components
    for component in ("act_j", "rd_j", "wr_j", "pre_j"):
        assert model["components_j"][component] == pytest.approx(n * truth_j[component], rel=1e-3), component
    # refresh: the UMC has no refresh event; one per tREFI per rank (the truth refreshes so too)
    assert model["components_j"]["ref_j"] == pytest.approx(n * truth_j["ref_j"], rel=0.02)
    # background: active vs precharged standby is estimated (open page) - within a few percent
    assert model["total_j"] == pytest.approx(n * core_energy_ddr5(spec, sub).core_j, rel=0.05)
    assert model["currents"]["kind"] == "datasheet"
    assert sum(model["split_j"].values()) == pytest.approx(model["total_j"], rel=1e-12)


def test_calibrated_memspec_is_used_and_said(pmu_trees: Path) -> None:
    """A memspec from ``calibrate --write-memspec`` (its ``calibration`` object) is named as such,
    and its currents are the ones used."""
    calibrated = genoa_spec({"physical": True, "violations": [], "status": "ok", "n_runs": 14})
    calibrated = calibrated.with_currents({"idd4r": 0.5 * calibrated.currents["idd4r"]})
    counters, _, _ = counted_window(pmu_trees, calibrated)
    model = umc_energy(calibrated, counters, source="genoa-calibrated.json")
    datasheet = umc_energy(genoa_spec(), counters)
    assert model["currents"]["kind"] == "calibrated"
    assert "imported from a node with DRAM sensors" in model["currents"]["text"]
    assert "14 runs" in model["currents"]["text"] and "genoa-calibrated.json" in model["currents"]["text"]
    assert model["components_j"]["rd_j"] < datasheet["components_j"]["rd_j"]
    assert currents_basis(genoa_spec()).text.startswith("datasheet currents of")


def test_a_window_without_cas_counts_is_refused_by_name() -> None:
    """Unknown is not zero: a channel whose CAS was not counted is an error naming it."""
    spec = genoa_spec()
    counters = {"window_s": 1.0, "ranks": 2, "channels": {"S0.umc3": {"act": 1e6, "cas_rd": math.nan,
                                                                        "cas_wr": 1e6, "dclk": 2.4e9}}}
    with pytest.raises(InputError, match=r"S0\.umc3.*cas_rd"):
        umc_energy(spec, counters)


def test_job_record_model_says_which_currents(pmu_trees: Path) -> None:
    """The daemon's job model (``counters_model``) on a DDR5 memspec books the joules under the
    currents' basis and says it; ``hdeem-watch job`` prints it."""
    from hdeem_watch.calibrate.counter_model import counters_model
    from hdeem_watch.cli.jobs import model_lines

    counters, _, _ = counted_window(pmu_trees, genoa_spec())
    plain = counters_model(genoa_spec(), counters, datasheet_a=None, calibrated_a=None)  # type: ignore[arg-type]
    assert plain["calibrated_j"] is None and plain["datasheet_j"] == pytest.approx(
        umc_energy(genoa_spec(), counters)["total_j"], rel=1e-12)
    imported = genoa_spec({"physical": True, "violations": [], "status": "ok", "n_runs": 9})
    model = counters_model(imported, counters, datasheet_a=None, calibrated_a=None)  # type: ignore[arg-type]
    assert model["datasheet_j"] is None and model["calibrated_j"] == pytest.approx(plain["datasheet_j"], rel=1e-12)
    assert model["currents"]["kind"] == "calibrated"
    lines = model_lines([{"ok": True, "node": "genoa1", "jobs": [{"job_id": "1", "state": "done", "model": model}]}])
    assert any("by component (calibrated, J)" in line for line in lines)
    assert any("currents: calibrated currents imported from a node with DRAM sensors" in line for line in lines)
