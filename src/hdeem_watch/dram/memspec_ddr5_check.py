"""Is a DDR5 memspec physically possible? Every per-command energy of DRAMPower's DDR5 model >= 0.

The DDR5 core model (:mod:`hdeem_watch.dram.energy_ddr5`) charges each command the current above
the background of its state, as the DDR4 one does, plus same-bank refresh. For each supply (VDD:
``idd*``, VPP: ``ipp*``), with ρ = ``factRho``, Iβ (= I0 unless ``iBeta_*`` is given), B banks in
G bank groups::

    activation   Iθ ≥ I1      Iθ = (I0·(RP + RAS) − Iβ·RP)/RAS,  I1 = (I3N + (B − 1)·Iρ)/B,
                              Iρ = I2N + ρ·(I3N − I2N)
    precharge    Iβ ≥ I2N
    ACT + PRE    I0 ≥ (I3N·RAS + I2N·RP)/(RAS + RP)
    read, write  I4R ≥ I3N,  I4W ≥ I3N
    refresh      I5X ≥ I3N             (I5X = IDD5B in refresh mode 1, IDD5F in mode 2)
    same-bank    I5C ≥ I_BG            I_BG = Iρ + G·(I1 − Iρ): the background of G open banks
    background   I3N ≥ I2N
    power-down   I2P ≤ I2N,  I3P ≤ I3N

Example:
    >>> import pathlib
    >>> from hdeem_watch.dram.memspec_ddr5 import load_memspec_ddr5
    >>> spec = load_memspec_ddr5(pathlib.Path(__file__).parents[3] / "examples" / "ddr5_drampower_test.json")
    >>> physical_violations_ddr5(spec)
    []
    >>> physical_violations_ddr5(spec.with_currents({"idd5c": 0.030}))
    ['same-bank refresh: IDD5C 30 mA < I_BG 36.98 mA (IDD3N 39.5, IDD2N 33.75 mA, rho 0.5, 2 bank groups)']
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from hdeem_watch.errors import InputError

if TYPE_CHECKING:
    from hdeem_watch.dram.memspec_ddr5 import MemSpecDDR5

#: Relative slack for rounding in datasheet-derived currents.
TOLERANCE = 1e-9


def _ma(value: float) -> str:
    return f"{value * 1e3:.4g}"


def _domain_violations(spec: MemSpecDDR5, prefix: str) -> list[str]:
    """Broken rules of one supply (``"idd"`` or ``"ipp"``), each a short phrase in mA."""
    cur, up = spec.currents, prefix.upper()
    i0, i2n, i3n = cur[f"{prefix}0"], cur[f"{prefix}2n"], cur[f"{prefix}3n"]
    beta_name = "ibeta_vdd" if prefix == "idd" else "ibeta_vpp"
    beta = cur.get(beta_name, i0)
    ras, rp, rho = spec.timings["RAS"], spec.timings["RP"], spec.fact_rho
    banks, groups = spec.nbr_of_banks, spec.nbr_of_bankgroups
    i_rho = i2n + rho * (i3n - i2n)
    i_1 = (i3n + (banks - 1) * i_rho) / banks
    i_theta = (i0 * (rp + ras) - beta * rp) / ras
    i_bg = i_rho + (i_1 - i_rho) * groups
    i5x = cur[spec.refresh_currents[0 if prefix == "idd" else 1]]
    eps = TOLERANCE * max(abs(v) for v in (i0, i2n, i3n, beta, 1e-3))
    checks = [
        (i_theta, i_1, f"activation: I_theta {_ma(i_theta)} mA ({up}0 {_ma(i0)}, iBeta {_ma(beta)}) < I1 "
                       f"{_ma(i_1)} mA ({up}3N {_ma(i3n)}, {up}2N {_ma(i2n)} mA, rho {rho:g})"),
        (beta, i2n, f"precharge: iBeta {_ma(beta)} mA < {up}2N {_ma(i2n)} mA"),
        (i0, (i3n * ras + i2n * rp) / (ras + rp),
         f"ACT+PRE: {up}0 {_ma(i0)} mA < the tRAS/tRC mix of {up}3N and {up}2N "
         f"{_ma((i3n * ras + i2n * rp) / (ras + rp))} mA (RAS {ras}, RP {rp} cycles)"),
        (cur[f"{prefix}4r"], i3n, f"read: {up}4R {_ma(cur[prefix + '4r'])} mA < {up}3N {_ma(i3n)} mA"),
        (cur[f"{prefix}4w"], i3n, f"write: {up}4W {_ma(cur[prefix + '4w'])} mA < {up}3N {_ma(i3n)} mA"),
        (i5x, i3n, f"refresh: {spec.refresh_currents[0 if prefix == 'idd' else 1].upper()} {_ma(i5x)} mA < "
                   f"{up}3N {_ma(i3n)} mA"),
        (cur[f"{prefix}5c"], i_bg, f"same-bank refresh: {up}5C {_ma(cur[prefix + '5c'])} mA < I_BG {_ma(i_bg)} mA "
                                   f"({up}3N {_ma(i3n)}, {up}2N {_ma(i2n)} mA, rho {rho:g}, {groups} bank groups)"),
        (i3n, i2n, f"background: {up}3N {_ma(i3n)} mA < {up}2N {_ma(i2n)} mA"),
        (i2n, cur[f"{prefix}2p"], f"power-down: {up}2P {_ma(cur[prefix + '2p'])} mA > {up}2N {_ma(i2n)} mA"),
        (i3n, cur[f"{prefix}3p"], f"power-down: {up}3P {_ma(cur[prefix + '3p'])} mA > {up}3N {_ma(i3n)} mA"),
    ]
    return [message for high, low, message in checks if high < low - eps]


def physical_violations_ddr5(spec: MemSpecDDR5) -> list[str]:
    """Every rule of the module docstring ``spec`` breaks, VDD first (empty: physical)."""
    return _domain_violations(spec, "idd") + _domain_violations(spec, "ipp")


def check_physical_ddr5(spec: MemSpecDDR5, where: str = "memspec") -> None:
    """Raise if ``spec`` would give a negative per-command energy.

    Raises:
        InputError: one line listing every broken rule and how to load the file anyway.
    """
    problems = physical_violations_ddr5(spec)
    if problems:
        raise InputError(f"{where}: unphysical currents (DRAMPower energy would be negative): "
                         f"{'; '.join(problems)}; load with allow_unphysical=True (--allow-unphysical) "
                         f"to study it anyway")
