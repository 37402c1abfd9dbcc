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

from hdeem_watch.dram.domain_energy import CoreTimes, add_domain_columns, add_domain_energy, supply_domains
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


def _times(spec: MemSpecDDR5) -> CoreTimes:
    """The equations' timings of a DDR5 memspec (reads BL/DR, writes DRAMPower's integer ⌊BL/DR⌋)."""
    return CoreTimes(ras=spec.timings["RAS"], rp=spec.timings["RP"], rfc=spec.trfc,
                     read_burst=spec.burst_length / spec.data_rate, write_burst=spec.burst_length // spec.data_rate,
                     banks=spec.nbr_of_banks, rho=spec.fact_rho)


def _rank_energy(spec: MemSpecDDR5, rank: RankStats) -> dict[str, float]:
    """Joules per component of one rank (both domains, all devices): DRAMPower v6.2's DDR5 formulas
    (the shared core, plus same-bank refresh against I_BG = Iρ + G·(I1 − Iρ))."""
    out = dict.fromkeys(COMPONENTS_DDR5, 0.0)
    times, tck, groups = _times(spec), spec.tck_s, spec.nbr_of_bankgroups
    rfcsb = spec.trfcsb * tck
    for domain in supply_domains(spec):
        i_rho, i_1 = add_domain_energy(out, rank, spec.currents, domain, times, tck)
        i_bg = i_rho + (i_1 - i_rho) * groups
        out["refsb_j"] += domain.volts * (spec.currents[f"{domain.prefix}5c"] - i_bg) * rfcsb * rank.refsb
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
    times, groups, rho, rfcsb = _times(spec), spec.nbr_of_bankgroups, spec.fact_rho, spec.trfcsb
    for domain in supply_domains(spec):
        k = domain.volts * spec.tck_s  # J per (A·cycle), all devices
        d1_d3n, d1_d2n = add_domain_columns(comp, const, r, spec.currents, domain, times, k, _INDEX)
        dbg_d3n = rho + groups * (d1_d3n - rho)  # ∂I_BG/∂I3N
        dbg_d2n = (1 - rho) + groups * (d1_d2n - (1 - rho))  # ∂I_BG/∂I2N
        p = domain.prefix
        comp["refsb_j"][_INDEX[f"{p}5c"]] += k * rfcsb * r.refsb
        comp["refsb_j"][_INDEX[f"{p}3n"]] -= k * rfcsb * dbg_d3n * r.refsb
        comp["refsb_j"][_INDEX[f"{p}2n"]] -= k * rfcsb * dbg_d2n * r.refsb


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
