"""The simulated node's own DIMM states and energy: power-down after idle time, refresh by temperature, I/O.

Per rank of a DIMM, over a stretch of sim time, the sim builds its own command statistics and
prices them with the DRAMPower v6 per-command energies (:func:`hdeem_watch.dram.energy.energy_columns`,
the physics; the statistics are not the model's):

- **Refresh** every ``tREFI``, every ``tREFI / 2`` above 85 °C (DDR4's extended temperature range).
- **Idle**: the controller closes the rows and puts the rank into precharge power-down (IDD2P); it
  wakes only to refresh (``tRFC`` active, ``tXP`` precharged standby per refresh).
- **Traffic**: rows stay open (active standby, IDD3N); the rank drops into active power-down (IDD3P)
  in the gaps between its requests longer than the controller's entry delay ``pd_entry_s``:
  ``fraction = (1 − bus share) · exp(−request rate · pd_entry_s)`` (arrivals as a Poisson stream).
  One precharge per activation (the row the activation replaced), plus ``tRP`` precharged per refresh.
- **I/O and termination** per burst: ``io_read_j`` per line read, ``io_write_j`` per line written
  (VDDQ drivers and on-die termination, not in the core model).

The daemon's model has none of this: its idle node is precharged standby (IDD2N) with a refresh every
``tREFI`` at any temperature, and no I/O.

Example:
    >>> from hdeem_watch.dram.memspec import preset
    >>> spec = preset("samsung-m393a1g43db0-cpb")
    >>> refresh_per_s(spec, 90.0) / refresh_per_s(spec, 80.0)
    2.0
    >>> idle = idle_rank(spec, 1.0, 40.0)
    >>> idle.cycles_pdnp / idle.cycles_total > 0.9
    True
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from hdeem_watch.dram.linear import linear_energy
from hdeem_watch.dram.stats import CommandStats, RankStats, refresh_interval

#: Above this DIMM temperature (°C) the controller refreshes twice as often.
HOT_C = 85.0
#: Components of the energy that are commands (the rest is background: standby, power-down, refresh).
COMMAND_COMPONENTS = ("act_j", "pre_j", "rd_j", "wr_j", "rda_j", "wra_j")


@dataclass(frozen=True)
class PowerPhysics:
    """What the sim's DIMMs do beyond the core model.

    Attributes:
        io_read_j: I/O energy per 64-byte line read (J, VDDQ drivers and termination).
        io_write_j: I/O energy per line written (J; writes terminate on the DIMM).
        pd_entry_s: idle time after which the controller puts a rank into power-down.
        hot_c: the temperature above which refresh doubles.
    """

    io_read_j: float = 0.45e-9
    io_write_j: float = 0.55e-9
    pd_entry_s: float = 200e-9
    hot_c: float = HOT_C


def dimm_peak_w(spec: Any, physics: PowerPhysics | None = None) -> float:
    """The most one DIMM can draw (W): every rank at the datasheet's largest operating current
    (IDD0, IDD4R, IDD4W) and IPP0 at once, plus I/O for a line every burst time — above anything the
    sim's truth (≤ 0.85 × datasheet, one burst at a time per channel) produces, and the bound no sample
    of a DIMM-pair sensor exceeds beyond its noise.

    >>> from hdeem_watch.dram.memspec import preset
    >>> round(dimm_peak_w(preset("samsung-m393a1g43db0-cpb")), 2)
    4.16
    """
    physics = physics or PowerPhysics()
    cur = spec.currents
    per_device = float(spec.vdd) * max(float(cur.get(n, 0.0)) for n in ("idd0", "idd4r", "idd4w")) \
        + float(spec.vpp) * float(cur.get("ipp0", 0.0))
    io = max(physics.io_read_j, physics.io_write_j) / (float(spec.burst_cycles) * float(spec.tck_s))
    return per_device * int(spec.nbr_of_devices) * int(spec.nbr_of_ranks) + io


def refresh_per_s(spec: Any, temp_c: float, hot_c: float = HOT_C) -> float:
    """All-bank refreshes per second of one rank at ``temp_c`` (doubled above ``hot_c``; DDR4 or DDR5).

    0 when the memspec gives no refresh interval (DRAMPower's DDR5 test memspec has ``REFI1 = 0``),
    as :func:`hdeem_watch.dram.stats.stretch_stats` does.
    """
    refi = refresh_interval(spec)
    if refi <= 0:
        return 0.0
    base = 1.0 / (refi * float(spec.tck_s))
    return 2.0 * base if temp_c > hot_c else base


def idle_rank(spec: Any, window_s: float, temp_c: float, hot_c: float = HOT_C) -> RankStats:
    """One idle rank over ``window_s``: precharge power-down, woken to refresh."""
    cycles = window_s / float(spec.tck_s)
    ref = refresh_per_s(spec, temp_c, hot_c) * window_s
    active = ref * float(spec.trfc)
    pre = ref * float(spec.timings["XP"])
    return RankStats(ref=ref, cycles_total=cycles, cycles_act=active, cycles_pre=pre,
                     cycles_pdnp=max(0.0, cycles - active - pre), bank_active_cycles=active)


def busy_rank(spec: Any, window_s: float, temp_c: float, reads: float, writes: float, activations: float,
              channel_lines: float, physics: PowerPhysics) -> RankStats:
    """One rank serving ``reads``/``writes`` bursts with ``activations`` over ``window_s`` (rows open)."""
    tck = float(spec.tck_s)
    cycles = window_s / tck
    ref = refresh_per_s(spec, temp_c, physics.hot_c) * window_s
    lines = reads + writes
    bus_share = min(1.0, channel_lines * float(spec.burst_cycles) / cycles) if cycles > 0 else 1.0
    rate = lines / window_s if window_s > 0 else 0.0
    powerdown = (1.0 - bus_share) * math.exp(-rate * physics.pd_entry_s) * max(0.0, cycles - ref * float(spec.trfc))
    pre = ref * float(spec.timings["RP"])
    active = max(0.0, cycles - powerdown - pre)
    return RankStats(act=activations, pre=activations, rd=reads, wr=writes, ref=ref, cycles_total=cycles,
                     cycles_act=active, cycles_pre=pre, cycles_pdna=powerdown, bank_active_cycles=active)


def split_columns(spec: Any, stats: CommandStats) -> tuple[np.ndarray, np.ndarray, float]:
    """(background columns, command columns, constant J) of ``stats`` (joules per ampere of each current)."""
    linear = linear_energy(spec, stats)
    command = np.sum([linear.component_columns[c] for c in COMMAND_COMPONENTS], axis=0)
    return np.asarray(linear.columns - command, dtype=float), np.asarray(command, dtype=float), float(linear.constant_j)


def idle_columns(spec: Any, hot: bool) -> tuple[np.ndarray, float]:
    """Joules per ampere per second of an idle DIMM (all ranks), cool or hot; and the constant (W)."""
    temp = HOT_C + 1.0 if hot else HOT_C - 1.0
    rank = idle_rank(spec, 1.0, temp)
    linear = linear_energy(spec, CommandStats(ranks=(rank,) * int(spec.nbr_of_ranks)))
    return np.asarray(linear.columns, dtype=float), float(linear.constant_j)
