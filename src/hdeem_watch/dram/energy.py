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

from hdeem_watch.dram.domain_energy import CoreTimes, add_domain_columns, add_domain_energy, supply_domains
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


def _times(spec: MemSpec) -> CoreTimes:
    """The equations' timings of a DDR4 memspec (reads and writes: BL/DR)."""
    return CoreTimes(ras=spec.timings["RAS"], rp=spec.timings["RP"], rfc=spec.trfc, read_burst=spec.burst_cycles,
                     write_burst=spec.burst_cycles, banks=spec.nbr_of_banks, rho=spec.fact_rho)


def _rank_energy(spec: MemSpec, rank: RankStats) -> dict[str, float]:
    """Joules per component of one rank (both domains, all devices): the DRAMPower v6 formulas."""
    out = dict.fromkeys(COMPONENTS, 0.0)
    times = _times(spec)
    for domain in supply_domains(spec):
        add_domain_energy(out, rank, spec.currents, domain, times, spec.tck_s)
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
    comp = {name: np.zeros(len(CURRENT_NAMES)) for name in COMPONENTS}
    const = dict.fromkeys(COMPONENTS, 0.0)
    times = _times(spec)
    for domain in supply_domains(spec):
        k = domain.volts * spec.tck_s  # J per (A·cycle), all devices
        for rank in stats.ranks:
            add_domain_columns(comp, const, rank, spec.currents, domain, times, k, _INDEX)
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
