"""Is a memspec physically possible? Every per-command energy of DRAMPower's DDR4 model must be >= 0.

The DRAMPower v6 core model (:mod:`hdeem_watch.dram.energy`) charges each command the current it
draws *above* the background of the state it happens in. Those increments are only non-negative
when the currents are ordered the way a real device draws them; for each supply (VDD: ``idd*``,
VPP: ``ipp*``), with ρ = ``factRho``, Iβ (= I0 unless the memspec gives ``iBeta_*``), B banks::

    activation   Iθ ≥ I1      Iθ = (I0·(RP + RAS) − Iβ·RP)/RAS,  I1 = (I3N + (B − 1)·Iρ)/B,
                              Iρ = I2N + ρ·(I3N − I2N)            (ρ = 1, Iβ = I0:  I0 ≥ I3N)
    precharge    Iβ ≥ I2N
    ACT + PRE    I0 ≥ (I3N·RAS + I2N·RP)/(RAS + RP)               (the tRAS/tRC-weighted mix)
    read, write  I4R ≥ I3N,  I4W ≥ I3N
    refresh      I5X ≥ I3N                                         (I5X = IDD5B, IDD5F2 or IDD5F4)
    background   I3N ≥ I2N  (an open bank costs more than none)
    power-down   I2P ≤ I2N,  I3P ≤ I3N

A memspec that breaks one of these (e.g. module currents divided evenly over the dies, which puts
IDD0 below IDD3N) gives negative activation or burst energies, and a calibration against it is
meaningless. :func:`physical_violations` lists every broken rule with the currents it involves.

The timings are held against JEDEC's DDR4 minimums (JESD79-4, as the Micron DDR4 die datasheets
print them) by :func:`timing_violations`: tAA (RL), tRCD and tRP at least the fastest speed bin of
the data rate (DDR4-1600J 13.75, -1866L 13.92, -2133N 13.13, -2400P 12.5, -2666T 12.75, -2933V 12.96,
-3200W 12.5 ns), tRAS the bin's minimum (35/34/33/32 ns), tRC ≥ tRAS + tRP, tWR 15 ns, tRTP
max(4 nCK, 7.5 ns), tWTR_S max(2 nCK, 2.5 ns), tWTR_L max(4 nCK, 7.5 ns), tXP max(4 nCK, 6 ns),
tCKE max(3 nCK, 5 ns), tRFC1 the density's (2/4/8/16 Gb: 160/260/350/550 ns), tXS ≥ tRFC1 + 10 ns,
tCCD_S, tRRD_S ≥ 4 nCK, and tREFI at most 7.8 µs. Nanoseconds become clocks by JEDEC's rounding
(``ceil(t/tCK − 0.026)``: its 0.974 correction). :func:`check_physical`, the load-time check, raises
the current violations and the speed-bin ones (tAA, tRCD, tRP, tRAS, tRC) as one line.

Example:
    >>> from hdeem_watch.dram.memspec import preset
    >>> physical_violations(preset("ddr4-2133-x8-4gb"))
    []
    >>> bad = preset("ddr4-2133-x8-4gb").with_currents({"idd0": 0.040})
    >>> physical_violations(bad)[0]
    'activation: IDD0 40 mA < I1 41.75 mA (IDD3N 41.75, IDD2N 36 mA, rho 1)'
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Protocol

from hdeem_watch.errors import InputError


class SpecView(Protocol):
    """What the checks read of a memspec (:class:`hdeem_watch.dram.memspec.MemSpec` has it all; this
    module does not import that one, so the two do not import each other)."""

    @property
    def currents(self) -> Mapping[str, float]: ...
    @property
    def timings(self) -> Mapping[str, int]: ...
    @property
    def nbr_of_banks(self) -> int: ...
    @property
    def nbr_of_rows(self) -> int: ...
    @property
    def nbr_of_columns(self) -> int: ...
    @property
    def width(self) -> int: ...
    @property
    def fact_rho(self) -> float: ...
    @property
    def tck_s(self) -> float: ...
    @property
    def refresh_currents(self) -> tuple[str, str]: ...

#: Relative slack for rounding in datasheet-derived currents (a few nA on tens of mA).
TOLERANCE = 1e-9


def _ma(value: float) -> str:
    return f"{value * 1e3:.4g}"


def _domain_violations(spec: SpecView, prefix: str) -> list[str]:
    """Broken rules of one supply (``"idd"`` or ``"ipp"``), each a short phrase in mA."""
    cur = spec.currents
    up = prefix.upper()
    i0, i2n, i3n = cur[f"{prefix}0"], cur[f"{prefix}2n"], cur[f"{prefix}3n"]
    beta_name = "ibeta_vdd" if prefix == "idd" else "ibeta_vpp"
    beta = cur.get(beta_name, i0)
    ras, rp, banks, rho = spec.timings["RAS"], spec.timings["RP"], spec.nbr_of_banks, spec.fact_rho
    i_rho = i2n + rho * (i3n - i2n)
    i_1 = (i3n + (banks - 1) * i_rho) / banks
    i_theta = (i0 * (rp + ras) - beta * rp) / ras
    ref_name = spec.refresh_currents[0 if prefix == "idd" else 1]
    scale = max(abs(v) for v in (i0, i2n, i3n, beta, 1e-3))
    eps = TOLERANCE * scale
    out: list[str] = []

    def below(low: float, high: float) -> bool:
        return low < high - eps

    if below(i_theta, i_1):
        head = f"{up}0 {_ma(i0)} mA" if beta_name not in cur else f"I_theta {_ma(i_theta)} mA ({up}0 {_ma(i0)}, iBeta {_ma(beta)})"
        out.append(f"activation: {head} < I1 {_ma(i_1)} mA ({up}3N {_ma(i3n)}, {up}2N {_ma(i2n)} mA, rho {rho:g})")
    if below(beta, i2n):
        name = f"{up}0" if beta_name not in cur else beta_name
        out.append(f"precharge: {name} {_ma(beta)} mA < {up}2N {_ma(i2n)} mA")
    mix = (i3n * ras + i2n * rp) / (ras + rp)
    if below(i0, mix):
        out.append(f"ACT+PRE: {up}0 {_ma(i0)} mA < the tRAS/tRC mix of {up}3N and {up}2N {_ma(mix)} mA "
                   f"(RAS {ras}, RP {rp} cycles)")
    for cmd, key in (("read", "4r"), ("write", "4w")):
        if below(cur[f"{prefix}{key}"], i3n):
            out.append(f"{cmd}: {up}{key.upper()} {_ma(cur[prefix + key])} mA < {up}3N {_ma(i3n)} mA")
    if below(cur[ref_name], i3n):
        out.append(f"refresh: {ref_name.upper()} {_ma(cur[ref_name])} mA < {up}3N {_ma(i3n)} mA")
    if below(i3n, i2n):
        out.append(f"background: {up}3N {_ma(i3n)} mA < {up}2N {_ma(i2n)} mA")
    if below(i2n, cur[f"{prefix}2p"]):
        out.append(f"power-down: {up}2P {_ma(cur[prefix + '2p'])} mA > {up}2N {_ma(i2n)} mA")
    if below(i3n, cur[f"{prefix}3p"]):
        out.append(f"power-down: {up}3P {_ma(cur[prefix + '3p'])} mA > {up}3N {_ma(i3n)} mA")
    return out


def physical_violations(spec: SpecView) -> list[str]:
    """Every rule of the module docstring ``spec`` breaks, VDD supply first (empty: physical).

    Args:
        spec: a loaded memspec.

    Returns:
        One phrase per broken rule naming the command, the currents (mA) and their values.
    """
    return _domain_violations(spec, "idd") + _domain_violations(spec, "ipp")


#: Data rate (MT/s) -> (tAA/tRCD/tRP, tRAS) minimum in ns of its fastest JESD79-4 speed bin.
SPEED_BIN_MIN_NS: dict[int, tuple[float, float]] = {
    1600: (13.75, 35.0), 1866: (13.92, 34.0), 2133: (13.13, 33.0), 2400: (12.5, 32.0),
    2666: (12.75, 32.0), 2933: (12.96, 32.0), 3200: (12.5, 32.0),
}
#: Die density (Gbit) -> tRFC1 minimum in ns (JESD79-4).
TRFC1_NS = {2: 160.0, 4: 260.0, 8: 350.0, 16: 550.0}
#: tREFI may not exceed 7.8 us (0-85 C).
TREFI_MAX_NS = 7800.0


def _clocks(ns: float, tck_ns: float, floor_nck: int = 0) -> int:
    """JEDEC's rounding of a minimum time to clocks (0.974 correction), at least ``floor_nck``."""
    return max(floor_nck, math.ceil(ns / tck_ns - 0.026))


def _timing_minimums(spec: SpecView, tck_ns: float) -> dict[str, tuple[int, str]]:
    """Timing key -> (minimum clocks, what it is) for the memspec's data rate and density."""
    rate = min(SPEED_BIN_MIN_NS, key=lambda r: abs(r - 2000.0 / tck_ns))
    taa, tras = SPEED_BIN_MIN_NS[rate]
    gbit = spec.nbr_of_banks * spec.nbr_of_rows * spec.nbr_of_columns * spec.width / (1 << 30)
    out = {key: (_clocks(taa, tck_ns), f"{taa} ns (DDR4-{rate} fastest bin)") for key in ("RL", "RCD", "RP")}
    out["RAS"] = (_clocks(tras, tck_ns), f"{tras:g} ns (DDR4-{rate})")
    out["WR"] = (_clocks(15.0, tck_ns), "15 ns")
    out["RTP"] = (_clocks(7.5, tck_ns, 4), "max(4 nCK, 7.5 ns)")
    out["WTR_S"] = (_clocks(2.5, tck_ns, 2), "max(2 nCK, 2.5 ns)")
    out["WTR_L"] = (_clocks(7.5, tck_ns, 4), "max(4 nCK, 7.5 ns)")
    out["XP"] = (_clocks(6.0, tck_ns, 4), "max(4 nCK, 6 ns)")
    out["CKE"] = (_clocks(5.0, tck_ns, 3), "max(3 nCK, 5 ns)")
    out["CCD_S"] = (4, "4 nCK")
    out["RRD_S"] = (4, "4 nCK")
    if (rfc := TRFC1_NS.get(round(gbit))) is not None:
        out["RFC1"] = (_clocks(rfc, tck_ns), f"{rfc:g} ns ({round(gbit)} Gb)")
        out["XS"] = (_clocks(rfc + 10.0, tck_ns), f"tRFC1 + 10 ns = {rfc + 10:g} ns")
    return out


#: The speed-bin timings (the load-time check holds these; the others only with ``every=True``).
SPEED_BIN_KEYS = ("RL", "RCD", "RP", "RAS")


def timing_violations(spec: SpecView, *, every: bool = True) -> list[str]:
    """Every timing below its JESD79-4 minimum (or tREFI above 7.8 us), one phrase each in clocks.

    Args:
        spec: the memspec.
        every: all rules of the module docstring; ``False``: the speed bin's only (tAA, tRCD, tRP,
            tRAS, tRC), what the load-time check enforces (reference memspecs of other tools carry
            refresh-exit times below the standard's, e.g. Ramulator's 8 Gb DDR4-2133P tXS of a 4 Gb die).
    """
    tck_ns = spec.tck_s * 1e9
    timings = spec.timings
    out = [f"t{key} {timings[key]} nCK < {need} nCK = {why}"
           for key, (need, why) in _timing_minimums(spec, tck_ns).items()
           if key in timings and timings[key] < need and (every or key in SPEED_BIN_KEYS)]
    if "RC" in timings and "RAS" in timings and "RP" in timings and timings["RC"] < timings["RAS"] + timings["RP"]:
        out.append(f"tRC {timings['RC']} nCK < tRAS + tRP = {timings['RAS'] + timings['RP']} nCK")
    if every and "REFI" in timings and timings["REFI"] * tck_ns > TREFI_MAX_NS * (1 + 1e-6):
        out.append(f"tREFI {timings['REFI']} nCK = {timings['REFI'] * tck_ns:.0f} ns > 7.8 us")
    return out


def check_physical(spec: SpecView, where: str = "memspec") -> None:
    """Raise if ``spec`` would give a negative per-command energy or a speed-bin timing below JEDEC's.

    Args:
        spec: a loaded memspec.
        where: the file or preset name used in the message.

    Raises:
        InputError: one line listing every broken rule and how to load the file anyway.
    """
    currents, timing = physical_violations(spec), timing_violations(spec, every=False)
    parts = ([f"unphysical currents (DRAMPower energy would be negative): {'; '.join(currents)}"] if currents else [])
    parts += [f"timings below JEDEC DDR4 minimums (JESD79-4): {'; '.join(timing)}"] if timing else []
    if parts:
        raise InputError(f"{where}: {'; '.join(parts)}; load with allow_unphysical=True (--allow-unphysical) "
                         f"to study it anyway")
