"""DDR4 core energy with DRAMPower v6 semantics, and its linear decomposition in the currents.

Per rank, for the VDD domain (IDDx, ``vdd``) and the VPP domain (IPPx, ``vpp``) alike, with
``k = V·tCK·D`` (D = devices per rank), B banks, b = BL/dataRate cycles per burst, ρ = factRho and
Iβ = iBeta (defaults: ρ = 1, Iβ = I0)::

    Iρ = I2N + ρ(I3N − I2N)          I1 = (I3N + (B − 1)Iρ)/B          Iθ = (I0(RP + RAS) − Iβ·RP)/RAS
    act    = k(Iθ − I1)·RAS·A            pre    = k(Iβ − I2N)·RP·P
    rd/rda = k(I4R − I3N)·b·N            wr/wra = k(I4W − I3N)·b·N          ref = k(I5X − I3N)·RFC·F
    bg_act = k·Iρ·T_act + k(I1 − Iρ)·ΣT_bank_act                            bg_pre = k·I2N·T_pre
    pdna   = k·I3P·T_pdna                pdnp   = k·I2P·T_pdnp              sref   = k·I6N·T_sr

(I5X and RFC follow ``RefMode``: IDD5B/RFC1, IDD5F2/RFC2 or IDD5F4/RFC4.) The total is summed over
ranks and both domains. The core energy is linear in every current: ``E = Σ_j c_j·I_j + e0``.

How Iβ enters the decomposition: Iβ is a model parameter, not one of :data:`CURRENT_NAMES`. When
the memspec gives no ``iBeta_vdd``/``iBeta_vpp``, Iβ *is* I0 (DRAMPower's default), so its
coefficient RP·(P − A) is folded into the I0 column and a calibrated I0 moves Iβ with it, exactly as
real DRAMPower would on the written-back memspec. When the memspec gives an explicit Iβ, it is held
fixed and its term goes into ``constant_j``. Either way ``columns @ currents + constant_j`` is the
core energy of the same memspec.

Example:
    >>> from hdeem_watch.dram.memspec import preset
    >>> from hdeem_watch.dram.stats import CommandStats, RankStats, stretch_stats
    >>> spec = preset("ddr4-2133-x8-4gb")
    >>> rank = RankStats(act=1, pre=1, rd=8, cycles_total=1000, cycles_act=100, cycles_pre=900,
    ...                  bank_active_cycles=100)
    >>> stats = CommandStats(ranks=(rank, RankStats(cycles_total=1000, cycles_pre=1000)))
    >>> energy = core_energy(spec, stats)
    >>> linear = energy_columns(spec, stats)
    >>> currents = [spec.currents[n] for n in linear.names]
    >>> bool(abs(linear.columns @ currents + linear.constant_j - energy.core_j) < 1e-20)
    True
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from hdeem_watch.dram.memspec import MemSpec
from hdeem_watch.dram.stats import CommandStats, RankStats, stretch_stats
from hdeem_watch.errors import InputError

#: Every current of a DDR4 memspec (amperes per device), the names of the linear columns.
CURRENT_NAMES: tuple[str, ...] = (
    "idd0", "idd2n", "idd3n", "idd4r", "idd4w", "idd5b", "idd6n", "idd2p", "idd3p",
    "ipp0", "ipp2n", "ipp3n", "ipp4r", "ipp4w", "ipp5b", "ipp6n", "ipp2p", "ipp3p",
    "idd5f2", "ipp5f2", "idd5f4", "ipp5f4",
)
#: Core energy components (joules), in the order of ``model energy --json``.
COMPONENTS: tuple[str, ...] = (
    "act_j", "pre_j", "rd_j", "wr_j", "rda_j", "wra_j", "ref_j", "bg_act_j", "bg_pre_j",
    "pdna_j", "pdnp_j", "sref_j",
)
#: :data:`COMPONENTS` grouped by what spends the energy (a job record's split, the report's figure).
COMPONENT_KINDS: dict[str, tuple[str, ...]] = {
    "background": ("bg_act_j", "bg_pre_j"),
    "activation": ("act_j", "pre_j"),
    "read": ("rd_j", "rda_j"),
    "write": ("wr_j", "wra_j"),
    "refresh": ("ref_j",),
    "power_down": ("pdna_j", "pdnp_j", "sref_j"),
}
_INDEX = {name: i for i, name in enumerate(CURRENT_NAMES)}


@dataclass(frozen=True)
class EnergyBreakdown:
    """Core energy of one channel.

    Attributes:
        components: joules per component (keys :data:`COMPONENTS`), summed over ranks and domains.
        core_j: the sum of the components.
        ranks: per rank, joules per component.
    """

    components: dict[str, float]
    core_j: float
    ranks: tuple[dict[str, float], ...] = field(default=())


@dataclass(frozen=True)
class LinearEnergy:
    """The core energy as ``columns @ currents + constant_j``.

    Attributes:
        names: the current names (:data:`CURRENT_NAMES`).
        columns: joules per ampere of each current (shape ``(len(names),)``).
        constant_j: the part that does not scale with any current (explicit Iβ terms), joules.
        component_columns: per component, its own columns (they sum to ``columns``).
        component_constants_j: per component, its own constant (they sum to ``constant_j``).
    """

    names: tuple[str, ...]
    columns: np.ndarray
    constant_j: float
    component_columns: dict[str, np.ndarray] = field(default_factory=dict)
    component_constants_j: dict[str, float] = field(default_factory=dict)

    def energy_j(self, currents: dict[str, float] | np.ndarray) -> float:
        """Core energy for other currents (a dict by name or an array in :attr:`names` order)."""
        values = np.asarray([currents[n] for n in self.names] if isinstance(currents, dict) else currents, float)
        return float(self.columns @ values + self.constant_j)


def _check_ranks(spec: MemSpec, stats: CommandStats) -> None:
    if len(stats.ranks) != spec.nbr_of_ranks:
        raise InputError(f"command statistics have {len(stats.ranks)} ranks; "
                         f"memspec {spec.memory_id!r} has {spec.nbr_of_ranks}")


def _domains(spec: MemSpec) -> tuple[tuple[str, float, str], ...]:
    """(prefix, voltage, iBeta name) of the VDD and VPP domains."""
    return (("idd", spec.vdd, "ibeta_vdd"), ("ipp", spec.vpp, "ibeta_vpp"))


def _rank_energy(spec: MemSpec, rank: RankStats) -> dict[str, float]:
    """Joules per component of one rank (both domains, all devices): the DRAMPower v6 formulas."""
    out = dict.fromkeys(COMPONENTS, 0.0)
    tck = spec.tck_s
    ras, rp, rfc = spec.timings["RAS"] * tck, spec.timings["RP"] * tck, spec.trfc * tck
    t_burst = spec.burst_cycles * tck
    banks, rho, devices = spec.nbr_of_banks, spec.fact_rho, spec.nbr_of_devices
    ref_vdd, ref_vpp = spec.refresh_currents
    for prefix, volt, beta_name in _domains(spec):
        cur = spec.currents
        i0, i2n, i3n = cur[f"{prefix}0"], cur[f"{prefix}2n"], cur[f"{prefix}3n"]
        ibeta = cur.get(beta_name, i0)
        i_rho = rho * (i3n - i2n) + i2n
        i_theta = (i0 * (rp + ras) - ibeta * rp) / ras
        i_1 = (i3n + (banks - 1) * i_rho) / banks
        i5x = cur[ref_vdd if prefix == "idd" else ref_vpp]
        v = volt * devices
        out["act_j"] += v * (i_theta - i_1) * ras * rank.act
        out["pre_j"] += v * (ibeta - i2n) * rp * rank.pre
        out["rd_j"] += v * (cur[f"{prefix}4r"] - i3n) * t_burst * rank.rd
        out["rda_j"] += v * (cur[f"{prefix}4r"] - i3n) * t_burst * rank.rda
        out["wr_j"] += v * (cur[f"{prefix}4w"] - i3n) * t_burst * rank.wr
        out["wra_j"] += v * (cur[f"{prefix}4w"] - i3n) * t_burst * rank.wra
        out["ref_j"] += v * (i5x - i3n) * rfc * rank.ref
        out["bg_act_j"] += v * (i_rho * rank.cycles_act + (i_1 - i_rho) * rank.bank_active_cycles) * tck
        out["bg_pre_j"] += v * i2n * rank.cycles_pre * tck
        out["pdna_j"] += v * cur[f"{prefix}3p"] * rank.cycles_pdna * tck
        out["pdnp_j"] += v * cur[f"{prefix}2p"] * rank.cycles_pdnp * tck
        out["sref_j"] += v * cur[f"{prefix}6n"] * rank.cycles_sref * tck
    return out


def core_energy(spec: MemSpec, stats: CommandStats) -> EnergyBreakdown:
    """Core energy of one channel from its command statistics (DRAMPower v6 DDR4 semantics).

    Args:
        spec: the memspec (currents per device; ``nbr_of_devices`` devices per rank).
        stats: per-rank counts and residency, one entry per rank of ``spec``.

    Raises:
        InputError: the statistics do not have one entry per rank of the memspec.
    """
    _check_ranks(spec, stats)
    ranks = tuple(_rank_energy(spec, rank) for rank in stats.ranks)
    components = {name: float(sum(rank[name] for rank in ranks)) for name in COMPONENTS}
    return EnergyBreakdown(components=components, core_j=float(sum(components.values())), ranks=ranks)


def energy_columns(spec: MemSpec, stats: CommandStats) -> LinearEnergy:
    """Joules per ampere of every current (and the current-free constant) for these statistics.

    ``core_energy(spec, stats).core_j == columns @ [spec.currents[n] for n in CURRENT_NAMES] +
    constant_j`` for any statistics; see the module docstring for how Iβ is treated.

    Raises:
        InputError: the statistics do not have one entry per rank of the memspec.
    """
    _check_ranks(spec, stats)
    n = len(CURRENT_NAMES)
    comp = {name: np.zeros(n) for name in COMPONENTS}
    const = dict.fromkeys(COMPONENTS, 0.0)
    tck = spec.tck_s
    ras, rp, rfc = spec.timings["RAS"], spec.timings["RP"], spec.trfc
    b, banks, rho = spec.burst_cycles, spec.nbr_of_banks, spec.fact_rho
    d1_d3n = (1 + (banks - 1) * rho) / banks  # ∂I1/∂I3N
    d1_d2n = (banks - 1) * (1 - rho) / banks  # ∂I1/∂I2N
    ref_vdd, ref_vpp = spec.refresh_currents
    for prefix, volt, beta_name in _domains(spec):
        k = volt * tck * spec.nbr_of_devices  # J per (A·cycle)
        i0, i2n, i3n = _INDEX[f"{prefix}0"], _INDEX[f"{prefix}2n"], _INDEX[f"{prefix}3n"]
        i5x = _INDEX[ref_vdd if prefix == "idd" else ref_vpp]
        explicit_beta = beta_name in spec.currents
        for r in stats.ranks:
            comp["act_j"][i0] += k * (rp + ras) * r.act
            comp["act_j"][i3n] -= k * ras * d1_d3n * r.act
            comp["act_j"][i2n] -= k * ras * d1_d2n * r.act
            comp["pre_j"][i2n] -= k * rp * r.pre
            # Iβ: −RP per activation (inside Iθ), +RP per precharge
            if explicit_beta:
                beta = spec.currents[beta_name]
                const["act_j"] -= k * rp * r.act * beta
                const["pre_j"] += k * rp * r.pre * beta
            else:
                comp["act_j"][i0] -= k * rp * r.act
                comp["pre_j"][i0] += k * rp * r.pre
            for name, count, cur in (("rd_j", r.rd, "4r"), ("rda_j", r.rda, "4r"),
                                     ("wr_j", r.wr, "4w"), ("wra_j", r.wra, "4w")):
                comp[name][_INDEX[f"{prefix}{cur}"]] += k * b * count
                comp[name][i3n] -= k * b * count
            comp["ref_j"][i5x] += k * rfc * r.ref
            comp["ref_j"][i3n] -= k * rfc * r.ref
            comp["bg_act_j"][i3n] += k * (rho * r.cycles_act + (d1_d3n - rho) * r.bank_active_cycles)
            comp["bg_act_j"][i2n] += k * ((1 - rho) * r.cycles_act + (d1_d2n - (1 - rho)) * r.bank_active_cycles)
            comp["bg_pre_j"][i2n] += k * r.cycles_pre
            comp["pdna_j"][_INDEX[f"{prefix}3p"]] += k * r.cycles_pdna
            comp["pdnp_j"][_INDEX[f"{prefix}2p"]] += k * r.cycles_pdnp
            comp["sref_j"][_INDEX[f"{prefix}6n"]] += k * r.cycles_sref
    columns = np.sum([comp[name] for name in COMPONENTS], axis=0)
    return LinearEnergy(names=CURRENT_NAMES, columns=columns, constant_j=float(sum(const.values())),
                        component_columns=comp, component_constants_j=const)


def component_energy(spec: MemSpec, groups: Sequence[tuple[CommandStats, float]], window_s: float,
                     currents_a: np.ndarray, *, name: str = "run") -> dict[str, float]:
    """Joules per component (:data:`COMPONENTS`) of ``groups`` (statistics, how many channels have
    them) stretched over the whole ``window_s`` (:func:`~hdeem_watch.dram.stats.stretch_stats`), with
    these currents (:data:`CURRENT_NAMES` order). The components sum to the calibration row's
    prediction for a window without an announced traffic time (a counter window, a job); a kernel
    run's row ends its traffic at the announced time (:func:`hdeem_watch.calibrate.rows.observation_from_run`)."""
    totals = dict.fromkeys(COMPONENTS, 0.0)
    for stats, n in groups:
        linear = energy_columns(spec, stretch_stats(spec, stats, window_s, name=name))
        for component in COMPONENTS:
            totals[component] += n * (float(linear.component_columns[component] @ currents_a)
                                      + float(linear.component_constants_j[component]))
    return totals
