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
meaningless. :func:`physical_violations` lists every broken rule with the currents it involves;
:func:`check_physical` raises them as one line.

Example:
    >>> from hdeem_watch.dram.memspec import preset
    >>> physical_violations(preset("ddr4-2133-x8-4gb"))
    []
    >>> bad = preset("ddr4-2133-x8-4gb").with_currents({"idd0": 0.040})
    >>> physical_violations(bad)[0]
    'activation: IDD0 40 mA < I1 41.75 mA (IDD3N 41.75, IDD2N 36 mA, rho 1)'
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from hdeem_watch.errors import InputError

if TYPE_CHECKING:
    from hdeem_watch.dram.memspec import MemSpec

#: Relative slack for rounding in datasheet-derived currents (a few nA on tens of mA).
TOLERANCE = 1e-9


def _ma(value: float) -> str:
    return f"{value * 1e3:.4g}"


def _domain_violations(spec: MemSpec, prefix: str) -> list[str]:
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


def physical_violations(spec: MemSpec) -> list[str]:
    """Every rule of the module docstring ``spec`` breaks, VDD supply first (empty: physical).

    Args:
        spec: a loaded memspec.

    Returns:
        One phrase per broken rule naming the command, the currents (mA) and their values.
    """
    return _domain_violations(spec, "idd") + _domain_violations(spec, "ipp")


def check_physical(spec: MemSpec, where: str = "memspec") -> None:
    """Raise if ``spec`` would give a negative per-command energy.

    Args:
        spec: a loaded memspec.
        where: the file or preset name used in the message.

    Raises:
        InputError: one line listing every broken rule and how to load the file anyway.
    """
    problems = physical_violations(spec)
    if problems:
        raise InputError(f"{where}: unphysical currents (DRAMPower energy would be negative): "
                         f"{'; '.join(problems)}; load with allow_unphysical=True (--allow-unphysical) "
                         f"to study it anyway")
