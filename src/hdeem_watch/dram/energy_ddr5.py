"""DDR5 core energy with DRAMPower v6.2 semantics (``core_calculation_DDR5``), and its linear columns.

Per rank, for the VDD domain (IDDx, ``vdd``) and the VPP domain (IPPx, ``vpp``) alike, with
``k = V·tCK·D`` (D devices per rank), B banks in G bank groups, ρ = factRho, Iβ = iBeta (defaults:
ρ = 1, Iβ = I0)::

    Iρ = I2N + ρ(I3N − I2N)     I1 = (I3N + (B − 1)Iρ)/B     Iθ = (I0(RP + RAS) − Iβ·RP)/RAS
    I_BG = Iρ + G(I1 − Iρ)       (the background of one open bank in each of the G groups)
    act    = k(Iθ − I1)·RAS·A           pre    = k(Iβ − I2N)·RP·P
    rd/rda = k(I4R − I3N)·BL/DR·N       wr/wra = k(I4W − I3N)·⌊BL/DR⌋·N
    ref    = k(I5X − I3N)·RFC·F         refsb  = k(I5C − I_BG)·RFCsb·S
    bg_act = k·Iρ·T_act + k(I1 − Iρ)·ΣT_bank_act                          bg_pre = k·I2N·T_pre
    pdna   = k·I3P·T_pdna               pdnp   = k·I2P·T_pdnp             sref   = k·I6N·T_sr

I5X/RFC are IDD5B/RFC1_slr (refresh mode 1) or IDD5F/RFC2_slr (mode 2); S counts REFSB commands.
The write burst is DRAMPower's integer ``BL / DR`` (the read burst is a float division; they differ
only for an odd BL/DR). The components are :data:`hdeem_watch.dram.energy.COMPONENTS` plus
``refsb_j``; the result types are the DDR4 module's (:class:`~hdeem_watch.dram.energy.EnergyBreakdown`,
:class:`~hdeem_watch.dram.energy.LinearEnergy`). Iβ enters the columns as in the DDR4 model: folded
into the I0 column when the memspec gives none, a constant when it does.

Example:
    >>> import pathlib
    >>> from hdeem_watch.dram.memspec_ddr5 import load_memspec_ddr5
    >>> from hdeem_watch.dram.stats import CommandStats, RankStats
    >>> spec = load_memspec_ddr5(pathlib.Path(__file__).parents[3] / "examples" / "ddr5_drampower_test.json")
    >>> rank = RankStats(act=1, pre=1, rd=8, refsb=2, cycles_total=1000, cycles_act=100, cycles_pre=900,
    ...                  bank_active_cycles=140)
    >>> energy = core_energy_ddr5(spec, CommandStats(ranks=(rank,)))
    >>> linear = energy_columns_ddr5(spec, CommandStats(ranks=(rank,)))
    >>> currents = [spec.currents[n] for n in linear.names]
    >>> bool(abs(linear.columns @ currents + linear.constant_j - energy.core_j) < 1e-20)
    True
"""

from __future__ import annotations

import numpy as np

from hdeem_watch.dram.energy import COMPONENTS, EnergyBreakdown, LinearEnergy
from hdeem_watch.dram.memspec_ddr5 import MemSpecDDR5
from hdeem_watch.dram.stats import CommandStats, RankStats
from hdeem_watch.errors import InputError

#: Every current of a DDR5 memspec (amperes per device), the names of the linear columns.
CURRENT_NAMES_DDR5: tuple[str, ...] = (
    "idd0", "idd2n", "idd3n", "idd4r", "idd4w", "idd5b", "idd5c", "idd6n", "idd2p", "idd3p",
    "ipp0", "ipp2n", "ipp3n", "ipp4r", "ipp4w", "ipp5b", "ipp5c", "ipp6n", "ipp2p", "ipp3p",
    "idd5f", "ipp5f",
)
#: DDR5 core energy components (joules): the DDR4 ones plus same-bank refresh.
COMPONENTS_DDR5: tuple[str, ...] = (*COMPONENTS, "refsb_j")
_INDEX = {name: i for i, name in enumerate(CURRENT_NAMES_DDR5)}


def _check_ranks(spec: MemSpecDDR5, stats: CommandStats) -> None:
    if len(stats.ranks) != spec.nbr_of_ranks:
        raise InputError(f"command statistics have {len(stats.ranks)} ranks; "
                         f"memspec {spec.memory_id!r} has {spec.nbr_of_ranks}")


def _domains(spec: MemSpecDDR5) -> tuple[tuple[str, float, str, str], ...]:
    """(prefix, voltage, iBeta name, all-bank refresh current) of the VDD and VPP domains."""
    ref_vdd, ref_vpp = spec.refresh_currents
    return (("idd", spec.vdd, "ibeta_vdd", ref_vdd), ("ipp", spec.vpp, "ibeta_vpp", ref_vpp))


def _rank_energy(spec: MemSpecDDR5, rank: RankStats) -> dict[str, float]:
    """Joules per component of one rank (both domains, all devices): DRAMPower v6.2's DDR5 formulas."""
    out = dict.fromkeys(COMPONENTS_DDR5, 0.0)
    tck = spec.tck_s
    ras, rp = spec.timings["RAS"] * tck, spec.timings["RP"] * tck
    rfc, rfcsb = spec.trfc * tck, spec.trfcsb * tck
    t_read, t_write = spec.burst_length / spec.data_rate * tck, (spec.burst_length // spec.data_rate) * tck
    banks, groups, rho = spec.nbr_of_banks, spec.nbr_of_bankgroups, spec.fact_rho
    cur = spec.currents
    for prefix, volt, beta_name, ref_name in _domains(spec):
        i0, i2n, i3n = cur[f"{prefix}0"], cur[f"{prefix}2n"], cur[f"{prefix}3n"]
        ibeta = cur.get(beta_name, i0)
        i_rho = rho * (i3n - i2n) + i2n
        i_theta = (i0 * (rp + ras) - ibeta * rp) / ras
        i_1 = (i3n + (banks - 1) * i_rho) / banks
        i_bg = i_rho + (i_1 - i_rho) * groups
        v = volt * spec.nbr_of_devices
        out["act_j"] += v * (i_theta - i_1) * ras * rank.act
        out["pre_j"] += v * (ibeta - i2n) * rp * rank.pre
        out["rd_j"] += v * (cur[f"{prefix}4r"] - i3n) * t_read * rank.rd
        out["rda_j"] += v * (cur[f"{prefix}4r"] - i3n) * t_read * rank.rda
        out["wr_j"] += v * (cur[f"{prefix}4w"] - i3n) * t_write * rank.wr
        out["wra_j"] += v * (cur[f"{prefix}4w"] - i3n) * t_write * rank.wra
        out["ref_j"] += v * (cur[ref_name] - i3n) * rfc * rank.ref
        out["refsb_j"] += v * (cur[f"{prefix}5c"] - i_bg) * rfcsb * rank.refsb
        out["bg_act_j"] += v * (i_rho * rank.cycles_act + (i_1 - i_rho) * rank.bank_active_cycles) * tck
        out["bg_pre_j"] += v * i2n * rank.cycles_pre * tck
        out["pdna_j"] += v * cur[f"{prefix}3p"] * rank.cycles_pdna * tck
        out["pdnp_j"] += v * cur[f"{prefix}2p"] * rank.cycles_pdnp * tck
        out["sref_j"] += v * cur[f"{prefix}6n"] * rank.cycles_sref * tck
    return out


def core_energy_ddr5(spec: MemSpecDDR5, stats: CommandStats) -> EnergyBreakdown:
    """Core energy of one DDR5 channel from its command statistics (keys :data:`COMPONENTS_DDR5`).

    Raises:
        InputError: the statistics do not have one entry per rank of the memspec.
    """
    _check_ranks(spec, stats)
    ranks = tuple(_rank_energy(spec, rank) for rank in stats.ranks)
    components = {name: float(sum(rank[name] for rank in ranks)) for name in COMPONENTS_DDR5}
    return EnergyBreakdown(components=components, core_j=float(sum(components.values())), ranks=ranks)


def _rank_columns(spec: MemSpecDDR5, r: RankStats, comp: dict[str, np.ndarray], const: dict[str, float]) -> None:
    """Add one rank's joules per ampere (and explicit-Iβ constants) to ``comp``/``const``."""
    ras, rp, rfc, rfcsb = spec.timings["RAS"], spec.timings["RP"], spec.trfc, spec.trfcsb
    b_read, b_write = spec.burst_length / spec.data_rate, spec.burst_length // spec.data_rate
    banks, groups, rho = spec.nbr_of_banks, spec.nbr_of_bankgroups, spec.fact_rho
    d1_d3n = (1 + (banks - 1) * rho) / banks  # ∂I1/∂I3N
    d1_d2n = (banks - 1) * (1 - rho) / banks  # ∂I1/∂I2N
    dbg_d3n = rho + groups * (d1_d3n - rho)  # ∂I_BG/∂I3N
    dbg_d2n = (1 - rho) + groups * (d1_d2n - (1 - rho))  # ∂I_BG/∂I2N
    for prefix, volt, beta_name, ref_name in _domains(spec):
        k = volt * spec.tck_s * spec.nbr_of_devices  # J per (A·cycle)
        i0, i2n, i3n = _INDEX[f"{prefix}0"], _INDEX[f"{prefix}2n"], _INDEX[f"{prefix}3n"]
        comp["act_j"][i0] += k * (rp + ras) * r.act
        comp["act_j"][i3n] -= k * ras * d1_d3n * r.act
        comp["act_j"][i2n] -= k * ras * d1_d2n * r.act
        comp["pre_j"][i2n] -= k * rp * r.pre
        if beta_name in spec.currents:  # an explicit Iβ is held: −RP per activation, +RP per precharge
            beta = spec.currents[beta_name]
            const["act_j"] -= k * rp * r.act * beta
            const["pre_j"] += k * rp * r.pre * beta
        else:
            comp["act_j"][i0] -= k * rp * r.act
            comp["pre_j"][i0] += k * rp * r.pre
        for name, count, key, burst in (("rd_j", r.rd, "4r", b_read), ("rda_j", r.rda, "4r", b_read),
                                        ("wr_j", r.wr, "4w", b_write), ("wra_j", r.wra, "4w", b_write)):
            comp[name][_INDEX[f"{prefix}{key}"]] += k * burst * count
            comp[name][i3n] -= k * burst * count
        comp["ref_j"][_INDEX[ref_name]] += k * rfc * r.ref
        comp["ref_j"][i3n] -= k * rfc * r.ref
        comp["refsb_j"][_INDEX[f"{prefix}5c"]] += k * rfcsb * r.refsb
        comp["refsb_j"][i3n] -= k * rfcsb * dbg_d3n * r.refsb
        comp["refsb_j"][i2n] -= k * rfcsb * dbg_d2n * r.refsb
        comp["bg_act_j"][i3n] += k * (rho * r.cycles_act + (d1_d3n - rho) * r.bank_active_cycles)
        comp["bg_act_j"][i2n] += k * ((1 - rho) * r.cycles_act + (d1_d2n - (1 - rho)) * r.bank_active_cycles)
        comp["bg_pre_j"][i2n] += k * r.cycles_pre
        comp["pdna_j"][_INDEX[f"{prefix}3p"]] += k * r.cycles_pdna
        comp["pdnp_j"][_INDEX[f"{prefix}2p"]] += k * r.cycles_pdnp
        comp["sref_j"][_INDEX[f"{prefix}6n"]] += k * r.cycles_sref


def energy_columns_ddr5(spec: MemSpecDDR5, stats: CommandStats) -> LinearEnergy:
    """Joules per ampere of every DDR5 current (and the current-free constant) for these statistics.

    ``core_energy_ddr5(spec, stats).core_j == columns @ [spec.currents[n] for n in
    CURRENT_NAMES_DDR5] + constant_j`` for any statistics (Iβ as in the module docstring).

    Raises:
        InputError: the statistics do not have one entry per rank of the memspec.
    """
    _check_ranks(spec, stats)
    comp = {name: np.zeros(len(CURRENT_NAMES_DDR5)) for name in COMPONENTS_DDR5}
    const = dict.fromkeys(COMPONENTS_DDR5, 0.0)
    for rank in stats.ranks:
        _rank_columns(spec, rank, comp, const)
    return LinearEnergy(names=CURRENT_NAMES_DDR5, columns=np.sum(list(comp.values()), axis=0),
                        constant_j=float(sum(const.values())), component_columns=comp,
                        component_constants_j=const)
