"""DDR5 core energy: parity with DRAMPower v6.2 on every reference case, linearity, hand cases."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hdeem_watch.dram.command_trace import read_command_trace
from hdeem_watch.dram.energy import COMPONENTS
from hdeem_watch.dram.energy_ddr5 import (
    COMPONENTS_DDR5,
    CURRENT_NAMES_DDR5,
    core_energy_ddr5,
    energy_columns_ddr5,
)
from hdeem_watch.dram.memspec_ddr5 import MemSpecDDR5, load_memspec_ddr5, parse_memspec_ddr5
from hdeem_watch.dram.stats import CommandStats, RankStats
from hdeem_watch.dram.trace_state_ddr5 import trace_stats_ddr5

#: <repo>/tests/data/drampower_ddr5
REF = Path(__file__).resolve().parents[1] / "data" / "drampower_ddr5"
#: our component -> DRAMPower BankEnergy key (summed over banks, devices, ranks)
BANK_KEYS = {"act_j": "ACT", "pre_j": "PRE", "rd_j": "RD", "wr_j": "WR", "rda_j": "RDA", "wra_j": "WRA",
             "ref_j": "REF_AB", "refsb_j": "REF_SB", "bg_pre_j": "BG_PRE"}
SHARED_KEYS = {"pdna_j": "E_PDNA", "pdnp_j": "E_PDNP", "sref_j": "E_sref"}


def reference_cases() -> list[tuple[str, str]]:
    """(memspec stem, trace stem) of every DRAMPower result file ``results/<memspec>/<trace>.cli.json``."""
    return sorted((path.parent.name, path.name.removesuffix(".cli.json"))
                  for path in (REF / "results").glob("*/*.cli.json"))


CASES = reference_cases()


def drampower_components(cli: dict[str, Any]) -> dict[str, float]:
    """DRAMPower's CLI JSON folded into our components (bg_act = per-bank star part + shared)."""
    core = cli["CoreEnergy"]
    out = {ours: sum(bank[key] for bank in core["BankEnergy"]) for ours, key in BANK_KEYS.items()}
    out["bg_act_j"] = sum(bank["BG_ACT"] for bank in core["BankEnergy"]) + core["E_bg_act_shared"]
    out.update({ours: core[key] for ours, key in SHARED_KEYS.items()})
    return out


def _case(memspec: str, trace: str) -> tuple[MemSpecDDR5, CommandStats, dict[str, Any]]:
    spec = load_memspec_ddr5(REF / "memspecs" / f"{memspec}.json")
    stats = trace_stats_ddr5(spec, read_command_trace(REF / "traces" / f"{trace}.csv"))
    cli = json.loads((REF / "results" / memspec / f"{trace}.cli.json").read_text())
    return spec, stats, cli


def test_reference_cases_cover_the_issue() -> None:
    """REFab in both modes, REFsb, power-down, self-refresh and mixed traffic, on 1 and 2 ranks."""
    traces = {trace for _, trace in CASES}
    for kind in ("refab", "refsb", "pdn", "sref", "mixed"):
        assert {f"{kind}_1r", f"{kind}_2r"} <= traces, kind
    assert ("ddr5_toy_1r_refmode2", "refab_1r") in CASES


@pytest.mark.parametrize(("memspec", "trace"), CASES, ids=[f"{m}-{t}" for m, t in CASES])
def test_every_component_equals_drampower(memspec: str, trace: str) -> None:
    """Trace -> state machine -> energy equals DRAMPower v6.2's CLI on every component to 1e-9."""
    spec, stats, cli = _case(memspec, trace)
    ours = core_energy_ddr5(spec, stats).components
    theirs = drampower_components(cli)
    for name in COMPONENTS_DDR5:
        assert ours[name] == pytest.approx(theirs[name], rel=1e-9, abs=1e-24), name
    interface = cli["InterfaceEnergy"]
    assert sum(ours.values()) == pytest.approx(cli["TotalEnergy"] - _interface_total(interface), rel=1e-9)
    # bg_act's two parts apart: the rank's active time (shared) and the banks' active time (per bank)
    shared = 0.0
    for prefix, volt in (("idd", spec.vdd), ("ipp", spec.vpp)):
        i2n, i3n = spec.currents[f"{prefix}2n"], spec.currents[f"{prefix}3n"]
        i_rho = i2n + spec.fact_rho * (i3n - i2n)
        shared += volt * spec.nbr_of_devices * i_rho * stats.total("cycles_act") * spec.tck_s
    assert shared == pytest.approx(cli["CoreEnergy"]["E_bg_act_shared"], rel=1e-9, abs=1e-24)


def stats_from_drampower(internal: dict[str, Any], spec: MemSpecDDR5) -> CommandStats:
    """CommandStats from DRAMPower's own counters (``<trace>.stats.json``, SimulationStats at T)."""
    banks, ranks = spec.nbr_of_banks, []
    for r, rank in enumerate(internal["rank_total"]):
        per_bank = internal["bank"][r * banks:(r + 1) * banks]

        def total(key: str, stats: list[dict[str, Any]] = per_bank) -> float:
            return float(sum(b["counter"][key] for b in stats))

        cycles = rank["cycles"]
        ranks.append(RankStats(
            act=total("act"), pre=total("pre"), rd=total("reads"), wr=total("writes"), rda=total("readAuto"),
            wra=total("writeAuto"), ref=total("refAllBank") / banks,
            refsb=total("refSameBank") / spec.nbr_of_bankgroups, cycles_total=float(internal["lastCommandTime"]),
            cycles_act=cycles["act"], cycles_pre=cycles["pre"], cycles_pdna=cycles["powerDownAct"],
            cycles_pdnp=cycles["powerDownPre"], cycles_sref=cycles["selfRefresh"],
            bank_active_cycles=float(sum(b["cycles"]["act"] for b in per_bank))))
    return CommandStats(ranks=tuple(ranks))


@pytest.mark.parametrize(("memspec", "trace"), CASES, ids=[f"{m}-{t}" for m, t in CASES])
def test_statistics_equal_drampower_counters(memspec: str, trace: str) -> None:
    """Every count and cycle figure of every rank equals DRAMPower's own counters exactly."""
    spec, stats, _ = _case(memspec, trace)
    internal = json.loads((REF / "results" / memspec / f"{trace}.stats.json").read_text())
    assert stats == stats_from_drampower(internal, spec)
    assert core_energy_ddr5(spec, stats).core_j == pytest.approx(internal["total_core"], rel=1e-9)


def _interface_total(interface: dict[str, Any]) -> float:
    return float(sum(side[kind] for side in interface.values() for kind in ("dynamicEnergy", "staticEnergy")))


@pytest.mark.parametrize(("memspec", "trace"), CASES, ids=[f"{m}-{t}" for m, t in CASES])
def test_columns_reproduce_energy_on_reference_cases(memspec: str, trace: str) -> None:
    """columns · currents + constant equals the core energy, per component and in total."""
    spec, stats, _ = _case(memspec, trace)
    energy = core_energy_ddr5(spec, stats)
    linear = energy_columns_ddr5(spec, stats)
    currents = np.array([spec.currents[n] for n in linear.names])
    assert linear.columns @ currents + linear.constant_j == pytest.approx(energy.core_j, rel=1e-12)
    for name in COMPONENTS_DDR5:
        got = linear.component_columns[name] @ currents + linear.component_constants_j[name]
        assert got == pytest.approx(energy.components[name], rel=1e-10, abs=1e-22), name
    # an explicit iBeta (the 1-rank toy memspec) is held constant; without one it folds into I0
    assert (linear.constant_j != 0.0) == ("iBeta_vdd" in spec.to_json_dict()["memspec"]["mempowerspec"]
                                          and stats.total("act") != stats.total("pre"))


def _random_stats(rng: np.random.Generator, ranks: int) -> CommandStats:
    out = []
    for _ in range(ranks):
        total = float(rng.integers(10_000, 1_000_000))
        parts = rng.dirichlet(np.ones(5)) * total
        out.append(RankStats(
            act=float(rng.integers(0, 1000)), pre=float(rng.integers(0, 1000)), rd=float(rng.integers(0, 9000)),
            wr=float(rng.integers(0, 9000)), rda=float(rng.integers(0, 100)), wra=float(rng.integers(0, 100)),
            ref=float(rng.integers(0, 100)), refsb=float(rng.integers(0, 400)), cycles_total=total,
            cycles_act=parts[0], cycles_pre=parts[1], cycles_pdna=parts[2], cycles_pdnp=parts[3],
            cycles_sref=parts[4], bank_active_cycles=parts[0] * rng.uniform(1, 16)))
    return CommandStats(ranks=tuple(out))


@pytest.mark.parametrize("ref_mode", [1, 2])
@pytest.mark.parametrize("explicit_beta", [True, False])
def test_linear_in_every_current_random(ref_mode: int, explicit_beta: bool) -> None:
    """Random statistics and currents (ρ, Iβ general, both refresh modes): columns predict the energy."""
    rng = np.random.default_rng(ref_mode * 2 + explicit_beta)
    data = json.loads((REF / "memspecs" / "ddr5_2r_allterms.json").read_text())
    data["memspec"]["memarchitecturespec"]["RefMode"] = ref_mode
    base = parse_memspec_ddr5(data, "x", allow_unphysical=True)
    for _ in range(20):
        stats = _random_stats(rng, base.nbr_of_ranks)
        currents = {n: float(rng.uniform(0.0, 0.2)) for n in CURRENT_NAMES_DDR5}
        if explicit_beta:
            currents.update(ibeta_vdd=float(rng.uniform(0, 0.1)), ibeta_vpp=float(rng.uniform(0, 0.01)))
        spec = base.with_currents(currents)
        linear = energy_columns_ddr5(spec, stats)
        energy = core_energy_ddr5(spec, stats)
        assert linear.energy_j({n: currents[n] for n in CURRENT_NAMES_DDR5}) == pytest.approx(energy.core_j, rel=1e-10)
        assert (linear.constant_j != 0.0) == explicit_beta
        # the columns are the energy's derivatives: moving one current moves the energy by its column
        name = CURRENT_NAMES_DDR5[int(rng.integers(len(CURRENT_NAMES_DDR5)))]
        moved = core_energy_ddr5(spec.with_currents({name: currents[name] + 0.01}), stats).core_j
        column = linear.columns[CURRENT_NAMES_DDR5.index(name)]
        assert moved - energy.core_j == pytest.approx(0.01 * column, rel=1e-6, abs=1e-18), name


def _toy() -> MemSpecDDR5:
    return load_memspec_ddr5(REF / "memspecs" / "ddr5_toy_1r.json")


def _stats_of(tmp_path: Path, spec: MemSpecDDR5, lines: str) -> CommandStats:
    path = tmp_path / "t.csv"
    path.write_text(lines)
    return trace_stats_ddr5(spec, read_command_trace(path))


def test_same_bank_refresh_by_hand(tmp_path: Path) -> None:
    """One REFSB: banks b and b+8 active for RFCsb; energy V·(I5C − I_BG)·tRFCsb (toy: ρ 0.5, 2 groups)."""
    spec = _toy()
    stats = _stats_of(tmp_path, spec, "10,REFSB,0,1,13,0,0\n100,END,0,0,0,0,0\n")
    rank = stats.ranks[0]
    assert (rank.refsb, rank.ref, rank.pre, rank.cycles_act, rank.bank_active_cycles) == (1, 0, 0, 20, 40)
    i2n, i3n, i5c = 0.03375, 0.0395, 0.110
    i_rho = i2n + 0.5 * (i3n - i2n)
    i_1 = (i3n + 15 * i_rho) / 16
    i_bg = i_rho + 2 * (i_1 - i_rho)
    tck = spec.tck_s
    energy = core_energy_ddr5(spec, stats).components
    assert energy["refsb_j"] == pytest.approx(1.2 * (i5c - i_bg) * 20 * tck, rel=1e-12)
    assert energy["bg_act_j"] == pytest.approx(1.2 * (i_rho * 20 + (i_1 - i_rho) * 40) * tck, rel=1e-12)
    assert energy["bg_pre_j"] == pytest.approx(1.2 * i2n * 80 * tck, rel=1e-12)


def test_presb_closes_the_bank_in_every_group(tmp_path: Path) -> None:
    """PRESB 2 precharges banks 2 and 10 (two counted precharges), not bank 3."""
    stats = _stats_of(tmp_path, _toy(), "0,ACT,0,0,2,0,0\n1,ACT,0,1,10,0,0\n2,ACT,0,0,3,0,0\n"
                                        "30,PRESB,0,0,2,0,0\n60,PRE,0,0,3,0,0\n100,END,0,0,0,0,0\n")
    rank = stats.ranks[0]
    assert (rank.act, rank.pre, rank.cycles_act, rank.bank_active_cycles) == (3, 3, 60, 30 + 29 + 58)


def test_refresh_mode_two_uses_idd5f_and_rfc2(tmp_path: Path) -> None:
    """RefMode 2: REFA lasts RFC2_slr (30) and is charged IDD5F; mode 1: RFC1_slr (25), IDD5B."""
    lines = "0,REFA,0,0,0,0,0\n100,END,0,0,0,0,0\n"
    data = json.loads((REF / "memspecs" / "ddr5_toy_1r.json").read_text())
    for mode, rfc, i5x in ((1, 25, 0.118), (2, 30, 0.135)):
        data["memspec"]["memarchitecturespec"]["RefMode"] = mode
        spec = parse_memspec_ddr5(data, "toy")
        stats = _stats_of(tmp_path, spec, lines)
        assert stats.ranks[0].cycles_act == rfc and stats.ranks[0].bank_active_cycles == 16 * rfc
        ref = core_energy_ddr5(spec, stats).components["ref_j"]
        assert ref == pytest.approx(1.2 * (i5x - 0.0395) * rfc * spec.tck_s, rel=1e-12)


def test_self_refresh_exit_closes_the_interval(tmp_path: Path) -> None:
    """SREFEN: a refresh, self-refresh from t + tRFC; SREFEX closes it (the core's rule)."""
    stats = _stats_of(tmp_path, _toy(), "10,SREFEN,0,0,0,0,0\n200,SREFEX,0,0,0,0,0\n300,END,0,0,0,0,0\n")
    rank = stats.ranks[0]
    assert (rank.ref, rank.cycles_act, rank.cycles_sref, rank.cycles_pre) == (1, 25, 200 - 35, 300 - 25 - 165)


def test_power_down_entry_and_exit_are_delayed(tmp_path: Path) -> None:
    """PDEA 2 cycles after ACT enters at ACT + RCD; PDXP right after PRE leaves at PRE + RP."""
    stats = _stats_of(tmp_path, _toy(), "0,ACT,0,0,1,0,0\n2,PDEA,0,0,0,0,0\n50,PDXA,0,0,0,0,0\n"
                                        "70,PRE,0,0,1,0,0\n71,PDEP,0,0,0,0,0\n72,PDXP,0,0,0,0,0\n"
                                        "100,END,0,0,0,0,0\n")
    rank = stats.ranks[0]
    assert (rank.cycles_pdna, rank.cycles_pdnp) == (50 - 13, 0)
    assert (rank.cycles_act, rank.bank_active_cycles) == (13 + 20, 13 + 20)


@pytest.mark.parametrize(("lines", "message"), [
    ("0,PDXA,0,0,0,0,0\n", "without a preceding PDEA"),
    ("0,PDEP,0,0,0,0,0\n5,SREFEN,0,0,0,0,0\n", "while the rank is in PDEP"),
    ("0,SREFEN,0,0,0,0,0\n10,SREFEX,0,0,0,0,0\n", "before the self-refresh starts"),
    ("0,ACT,0,0,16,0,0\n", "bank 16 out of range"),
])
def test_power_state_order_errors(tmp_path: Path, lines: str, message: str) -> None:
    from hdeem_watch.errors import InputError

    with pytest.raises(InputError, match=message):
        _stats_of(tmp_path, _toy(), lines)


@pytest.mark.slow
def test_cli_json_has_ddr4_keys_plus_refsb(tmp_path: Path) -> None:
    """``model energy --json`` on a DDR5 memspec: DDR4's component keys plus refsb_j, same numbers."""
    memspec, trace = REF / "memspecs" / "ddr5_2r_allterms.json", REF / "traces" / "refsb_2r.csv"
    done = subprocess.run([sys.executable, "-m", "hdeem_watch", "model", "energy", "--memspec", str(memspec),
                           "--trace", str(trace), "--json"], capture_output=True, text=True, check=True)
    data = json.loads(done.stdout)
    assert list(data["components"]) == [*COMPONENTS, "refsb_j"]
    assert [rank["refsb"] for rank in data["counts"]] == [22.0, 22.0]
    cli = json.loads((REF / "results" / "ddr5_2r_allterms" / "refsb_2r.cli.json").read_text())
    assert data["components"]["refsb_j"] == pytest.approx(drampower_components(cli)["refsb_j"], rel=1e-9)
    table = subprocess.run([sys.executable, "-m", "hdeem_watch", "model", "energy", "--memspec", str(memspec),
                            "--trace", str(trace)], capture_output=True, text=True, check=True).stdout
    assert "refsb" in table


def test_ddr4_memspec_refuses_ddr5_commands(tmp_path: Path) -> None:
    """A REFSB or PRESB in a trace for a DDR4 memspec is named, not silently ignored."""
    from hdeem_watch.dram.memspec import preset
    from hdeem_watch.dram.trace_state import trace_stats
    from hdeem_watch.errors import InputError

    path = tmp_path / "t.csv"
    path.write_text("0,ACT,0,0,1,0,0\n30,PRESB,0,0,1,0,0\n100,END,0,0,0,0,0\n")
    with pytest.raises(InputError, match=r"line 2: PRESB is a DDR5 command; memspec .* is DDR4"):
        trace_stats(preset("ddr4-2133-x8-4gb"), read_command_trace(path))
