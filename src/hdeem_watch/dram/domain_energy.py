"""DRAMPower v6's core energy equations of one supply domain of one rank (shared by DDR4 and DDR5).

Both standards charge ACT, PRE, RD/RDA, WR/WRA, all-bank refresh, the background (ρ and Iβ) and the
power-down and self-refresh states the same way; they differ in the burst length of a write (DDR5's
integer BL/DR), the refresh current of the refresh mode and DDR5's same-bank refresh, which the
callers (:mod:`hdeem_watch.dram.energy`, :mod:`hdeem_watch.dram.energy_ddr5`) add themselves.
:func:`add_domain_energy` gives joules, :func:`add_domain_columns` the same joules as columns per
ampere (the linear form the calibration fits), so ``energy == columns @ currents + constant``.

Example:
    >>> from hdeem_watch.dram.stats import RankStats
    >>> times = CoreTimes(ras=28, rp=14, rfc=260, read_burst=4, write_burst=4, banks=16, rho=1.0)
    >>> out = dict.fromkeys(("act_j", "pre_j", "rd_j", "rda_j", "wr_j", "wra_j", "ref_j", "bg_act_j",
    ...                      "bg_pre_j", "pdna_j", "pdnp_j", "sref_j"), 0.0)
    >>> cur = {"idd0": 0.06, "idd2n": 0.04, "idd3n": 0.05, "idd4r": 0.15, "idd4w": 0.14, "idd5b": 0.2,
    ...        "idd2p": 0.03, "idd3p": 0.04, "idd6n": 0.03}
    >>> _ = add_domain_energy(out, RankStats(rd=10), cur, Domain("idd", 1.2, "ibeta_vdd", "idd5b"), times, 1e-9)
    >>> round(out["rd_j"] / (1.2 * (0.15 - 0.05) * 4e-9 * 10), 12)
    1.0
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from hdeem_watch.dram.stats import RankStats


@dataclass(frozen=True)
class Domain:
    """One supply domain of a rank.

    Attributes:
        prefix: ``"idd"`` (VDD) or ``"ipp"`` (VPP).
        volts: the supply voltage times the devices of the rank.
        beta_name: the domain's optional Iβ current (``"ibeta_vdd"``).
        refresh_current: the all-bank refresh current of the refresh mode (``"idd5b"``, ``"idd5f"``, ...).
    """

    prefix: str
    volts: float
    beta_name: str
    refresh_current: str


class _Supplies(Protocol):
    """What :func:`supply_domains` reads of a memspec (DDR4's ``MemSpec`` and ``MemSpecDDR5`` both)."""

    @property
    def vdd(self) -> float: ...

    @property
    def vpp(self) -> float: ...

    @property
    def nbr_of_devices(self) -> int: ...

    @property
    def refresh_currents(self) -> tuple[str, str]: ...


def supply_domains(spec: _Supplies) -> tuple[Domain, Domain]:
    """The VDD and VPP domains of a rank of ``spec`` (voltage × devices, Iβ, refresh current of the mode)."""
    ref_vdd, ref_vpp = spec.refresh_currents
    devices = spec.nbr_of_devices
    return (Domain("idd", spec.vdd * devices, "ibeta_vdd", ref_vdd),
            Domain("ipp", spec.vpp * devices, "ibeta_vpp", ref_vpp))


@dataclass(frozen=True)
class CoreTimes:
    """The timings of the equations in cycles: tRAS, tRP, tRFC of the mode, the read and write burst
    (BL/DR), and the bank-wise model's banks and ρ."""

    ras: float
    rp: float
    rfc: float
    read_burst: float
    write_burst: float
    banks: int
    rho: float


def add_domain_energy(out: dict[str, float], rank: RankStats, cur: Mapping[str, float], domain: Domain,
                      times: CoreTimes, tck: float) -> tuple[float, float]:
    """Add one domain's joules of ``rank`` to ``out`` (by component); returns (Iρ, I1) for the caller's
    own terms (DDR5's same-bank refresh)."""
    p, v, t = domain.prefix, domain.volts, times
    i0, i2n, i3n = cur[f"{p}0"], cur[f"{p}2n"], cur[f"{p}3n"]
    ras, rp, rfc = t.ras * tck, t.rp * tck, t.rfc * tck
    t_read, t_write = t.read_burst * tck, t.write_burst * tck
    ibeta = cur.get(domain.beta_name, i0)
    i_rho = t.rho * (i3n - i2n) + i2n
    i_theta = (i0 * (rp + ras) - ibeta * rp) / ras
    i_1 = (i3n + (t.banks - 1) * i_rho) / t.banks
    out["act_j"] += v * (i_theta - i_1) * ras * rank.act
    out["pre_j"] += v * (ibeta - i2n) * rp * rank.pre
    out["rd_j"] += v * (cur[f"{p}4r"] - i3n) * t_read * rank.rd
    out["rda_j"] += v * (cur[f"{p}4r"] - i3n) * t_read * rank.rda
    out["wr_j"] += v * (cur[f"{p}4w"] - i3n) * t_write * rank.wr
    out["wra_j"] += v * (cur[f"{p}4w"] - i3n) * t_write * rank.wra
    out["ref_j"] += v * (cur[domain.refresh_current] - i3n) * rfc * rank.ref
    out["bg_act_j"] += v * (i_rho * rank.cycles_act + (i_1 - i_rho) * rank.bank_active_cycles) * tck
    out["bg_pre_j"] += v * i2n * rank.cycles_pre * tck
    out["pdna_j"] += v * cur[f"{p}3p"] * rank.cycles_pdna * tck
    out["pdnp_j"] += v * cur[f"{p}2p"] * rank.cycles_pdnp * tck
    out["sref_j"] += v * cur[f"{p}6n"] * rank.cycles_sref * tck
    return i_rho, i_1


def add_domain_columns(comp: dict[str, np.ndarray], const: dict[str, float], r: RankStats,
                       cur: Mapping[str, float], domain: Domain, times: CoreTimes, k: float,
                       index: Mapping[str, int]) -> tuple[float, float]:
    """Add one domain's joules per ampere of ``r`` to ``comp`` (columns by current ``index``) and
    an explicit Iβ's joules to ``const``; ``k`` = joules per ampere-cycle (V·tCK·devices). Returns
    (∂I1/∂I3N, ∂I1/∂I2N) for the caller's own terms."""
    p, t = domain.prefix, times
    i0, i2n, i3n = index[f"{p}0"], index[f"{p}2n"], index[f"{p}3n"]
    d1_d3n = (1 + (t.banks - 1) * t.rho) / t.banks  # ∂I1/∂I3N
    d1_d2n = (t.banks - 1) * (1 - t.rho) / t.banks  # ∂I1/∂I2N
    comp["act_j"][i0] += k * (t.rp + t.ras) * r.act
    comp["act_j"][i3n] -= k * t.ras * d1_d3n * r.act
    comp["act_j"][i2n] -= k * t.ras * d1_d2n * r.act
    comp["pre_j"][i2n] -= k * t.rp * r.pre
    if domain.beta_name in cur:  # an explicit Iβ is held: −RP per activation (inside Iθ), +RP per precharge
        beta = cur[domain.beta_name]
        const["act_j"] -= k * t.rp * r.act * beta
        const["pre_j"] += k * t.rp * r.pre * beta
    else:
        comp["act_j"][i0] -= k * t.rp * r.act
        comp["pre_j"][i0] += k * t.rp * r.pre
    for name, count, key, burst in (("rd_j", r.rd, "4r", t.read_burst), ("rda_j", r.rda, "4r", t.read_burst),
                                    ("wr_j", r.wr, "4w", t.write_burst), ("wra_j", r.wra, "4w", t.write_burst)):
        comp[name][index[f"{p}{key}"]] += k * burst * count
        comp[name][i3n] -= k * burst * count
    comp["ref_j"][index[domain.refresh_current]] += k * t.rfc * r.ref
    comp["ref_j"][i3n] -= k * t.rfc * r.ref
    comp["bg_act_j"][i3n] += k * (t.rho * r.cycles_act + (d1_d3n - t.rho) * r.bank_active_cycles)
    comp["bg_act_j"][i2n] += k * ((1 - t.rho) * r.cycles_act + (d1_d2n - (1 - t.rho)) * r.bank_active_cycles)
    comp["bg_pre_j"][i2n] += k * r.cycles_pre
    comp["pdna_j"][index[f"{p}3p"]] += k * r.cycles_pdna
    comp["pdnp_j"][index[f"{p}2p"]] += k * r.cycles_pdnp
    comp["sref_j"][index[f"{p}6n"]] += k * r.cycles_sref
    return d1_d3n, d1_d2n
