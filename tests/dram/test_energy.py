"""DDR4 core energy: every component of every DRAMPower v6.2 reference case, and linearity."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hdeem_watch.dram.energy import COMPONENTS, CURRENT_NAMES, core_energy, energy_columns
from hdeem_watch.dram.memspec import load_memspec, preset
from hdeem_watch.dram.stats import CommandStats, RankStats
from hdeem_watch.errors import InputError

#: our component -> DRAMPower BankEnergy key (summed over banks, devices, ranks)
BANK_KEYS = {"act_j": "ACT", "pre_j": "PRE", "rd_j": "RD", "wr_j": "WR", "rda_j": "RDA",
             "wra_j": "WRA", "ref_j": "REF_AB", "bg_pre_j": "BG_PRE"}
SHARED_KEYS = {"pdna_j": "E_PDNA", "pdnp_j": "E_PDNP", "sref_j": "E_sref"}


def drampower_components(cli: dict[str, Any]) -> dict[str, float]:
    """DRAMPower's CLI JSON folded into our components (bg_act = per-bank star part + shared)."""
    core = cli["CoreEnergy"]
    out = {ours: sum(bank[key] for bank in core["BankEnergy"]) for ours, key in BANK_KEYS.items()}
    out["bg_act_j"] = sum(bank["BG_ACT"] for bank in core["BankEnergy"]) + core["E_bg_act_shared"]
    out.update({ours: core[key] for ours, key in SHARED_KEYS.items()})
    return out


def stats_from_drampower(internal: dict[str, Any], banks: int) -> CommandStats:
    """CommandStats from DRAMPower's own internal counters (<trace>.stats.json)."""
    ranks = []
    for r, rank in enumerate(internal["stats"]["rank_total"]):
        bank_stats = internal["stats"]["bank"][r * banks:(r + 1) * banks]

        def total(key: str, stats: list[dict[str, Any]] = bank_stats) -> float:
            return float(sum(b["counter"][key] for b in stats))

        cycles = rank["cycles"]
        ranks.append(RankStats(
            act=total("act"), pre=total("pre"), rd=total("reads"), wr=total("writes"),
            rda=total("readAuto"), wra=total("writeAuto"), ref=total("refAllBank") / banks,
            cycles_total=float(internal["lastCommandTime"]), cycles_act=cycles["act"],
            cycles_pre=cycles["pre"], cycles_pdna=cycles["powerDownAct"],
            cycles_pdnp=cycles["powerDownPre"], cycles_sref=cycles["selfRefresh"],
            bank_active_cycles=float(sum(b["cycles"]["act"] for b in bank_stats))))
    return CommandStats(ranks=tuple(ranks))


def assert_components_match(ours: dict[str, float], theirs: dict[str, float], scale: float = 1.0) -> None:
    for name in COMPONENTS:
        expected = theirs[name] * scale
        assert ours[name] == pytest.approx(expected, rel=1e-9, abs=1e-25), name


def test_components_match_drampower_from_its_counters(drampower_ref: Path, reference_memspec_path,  # type: ignore[no-untyped-def]
                                                      drampower_case: tuple[str, str]) -> None:
    """Fed DRAMPower's own counters, every core component equals DRAMPower's to 1e-9 relative."""
    config, trace = drampower_case
    spec = load_memspec(reference_memspec_path(config))
    results = drampower_ref / "results" / config
    cli = json.loads((results / f"{trace}.cli.json").read_text())
    stats = stats_from_drampower(json.loads((results / f"{trace}.stats.json").read_text()), spec.nbr_of_banks)
    assert stats.total("act") > 0 or trace == "idle_refresh"
    energy = core_energy(spec, stats)
    theirs = drampower_components(cli)
    assert_components_match(energy.components, theirs)
    internal = json.loads((results / f"{trace}.stats.json").read_text())
    assert energy.core_j == pytest.approx(internal["total_core"], rel=1e-9)


def test_columns_reproduce_energy(drampower_ref: Path, reference_memspec_path,  # type: ignore[no-untyped-def]
                                  drampower_case: tuple[str, str]) -> None:
    """columns · currents + constant equals the core energy, per component and in total."""
    config, trace = drampower_case
    spec = load_memspec(reference_memspec_path(config))
    stats = stats_from_drampower(
        json.loads((drampower_ref / "results" / config / f"{trace}.stats.json").read_text()), spec.nbr_of_banks)
    energy = core_energy(spec, stats)
    linear = energy_columns(spec, stats)
    assert linear.names == CURRENT_NAMES
    currents = np.array([spec.currents[n] for n in linear.names])
    assert linear.columns @ currents + linear.constant_j == pytest.approx(energy.core_j, rel=1e-12)
    for name in COMPONENTS:
        got = linear.component_columns[name] @ currents + linear.component_constants_j[name]
        assert got == pytest.approx(energy.components[name], rel=1e-10, abs=1e-22), name
    # only an explicit iBeta is held constant (its ACT and PRE parts cancel when A == P)
    assert (linear.component_constants_j["act_j"] != 0.0) == (config == "allterms" and stats.total("act") > 0)


def test_eight_devices_is_exactly_eight_times(drampower_ref: Path, reference_memspec_path) -> None:  # type: ignore[no-untyped-def]
    """Currents are per device: the 8-device memspec gives 8x the 1-device core energy."""
    internal = json.loads((drampower_ref / "results" / "1dev" / "stream_read.stats.json").read_text())
    stats = stats_from_drampower(internal, 16)
    one = core_energy(load_memspec(reference_memspec_path("1dev")), stats)
    eight = core_energy(preset("ddr4-2133-x8-4gb"), stats)
    assert eight.core_j == pytest.approx(8 * one.core_j, rel=1e-12)


def _random_stats(rng: np.random.Generator, ranks: int) -> CommandStats:
    out = []
    for _ in range(ranks):
        total = float(rng.integers(10_000, 1_000_000))
        parts = rng.dirichlet(np.ones(5)) * total
        out.append(RankStats(
            act=float(rng.integers(0, 1000)), pre=float(rng.integers(0, 1000)), rd=float(rng.integers(0, 9000)),
            wr=float(rng.integers(0, 9000)), rda=float(rng.integers(0, 100)), wra=float(rng.integers(0, 100)),
            ref=float(rng.integers(0, 100)), cycles_total=total, cycles_act=parts[0], cycles_pre=parts[1],
            cycles_pdna=parts[2], cycles_pdnp=parts[3], cycles_sref=parts[4],
            bank_active_cycles=parts[0] * rng.uniform(1, 16)))
    return CommandStats(ranks=tuple(out))


@pytest.mark.parametrize("ref_mode", [1, 2, 4])
def test_linear_in_every_current_random(reference_memspec_path, ref_mode: int) -> None:  # type: ignore[no-untyped-def]
    """For random statistics and random currents (ρ, Iβ general) the columns predict the energy."""
    rng = np.random.default_rng(ref_mode)
    data = json.loads(reference_memspec_path("allterms").read_text())
    data["memspec"]["memarchitecturespec"]["RefMode"] = ref_mode
    from hdeem_watch.dram.memspec import parse_memspec

    # the currents are drawn at random below (and RefMode 2/4 currents start at 0): any order goes
    base = parse_memspec(data, "x", allow_unphysical=True)
    for _ in range(20):
        stats = _random_stats(rng, base.nbr_of_ranks)
        currents = {n: float(rng.uniform(0.0, 0.2)) for n in CURRENT_NAMES}
        spec = base.with_currents(currents)
        linear = energy_columns(spec, stats)
        assert linear.energy_j(currents) == pytest.approx(core_energy(spec, stats).core_j, rel=1e-10)
        # a spec without explicit iBeta ties Iβ to I0: still exactly linear, constant 0
        tied = json.loads(json.dumps(spec.to_json_dict()))
        for key in ("iBeta_vdd", "iBeta_vpp"):
            del tied["memspec"]["mempowerspec"][key]
        tied_spec = parse_memspec(tied, "tied", allow_unphysical=True)
        tied_linear = energy_columns(tied_spec, stats)
        assert tied_linear.constant_j == 0.0
        assert tied_linear.energy_j(currents) == pytest.approx(core_energy(tied_spec, stats).core_j, rel=1e-10)


def test_classic_columns_with_default_rho_beta() -> None:
    """With ρ = 1 and Iβ = I0 the columns are DESIGN.md's: c(IDD0) = (RAS+RP)·A, c(IDD3N) = T_act − ..."""
    spec = preset("ddr4-2133-x8-4gb")
    rank = RankStats(act=10, pre=10, rd=100, wr=50, ref=2, cycles_total=100_000, cycles_act=30_000,
                     cycles_pre=60_000, cycles_pdna=5_000, cycles_pdnp=3_000, cycles_sref=2_000,
                     bank_active_cycles=70_000)
    stats = CommandStats(ranks=(rank, RankStats(cycles_total=100_000, cycles_pre=100_000)))
    col = dict(zip(CURRENT_NAMES, energy_columns(spec, stats).columns / (spec.vdd * spec.tck_s * 8)))
    assert col["idd0"] == pytest.approx((36 + 15) * 10)
    assert col["idd4r"] == pytest.approx(4 * 100) and col["idd4w"] == pytest.approx(4 * 50)
    assert col["idd5b"] == pytest.approx(278 * 2)
    assert col["idd3n"] == pytest.approx(30_000 - 36 * 10 - 4 * 150 - 278 * 2)
    assert col["idd2n"] == pytest.approx(60_000 + 100_000 - 15 * 10)
    assert (col["idd3p"], col["idd2p"], col["idd6n"]) == pytest.approx((5_000, 3_000, 2_000))
    assert col["idd5f2"] == 0.0 and col["idd5f4"] == 0.0


def test_rank_count_mismatch_is_input_error() -> None:
    """Statistics with the wrong number of ranks are rejected, not silently mis-summed."""
    with pytest.raises(InputError, match="ranks"):
        core_energy(preset("ddr4-2133-x8-4gb"), CommandStats(ranks=(RankStats(),)))
