"""Hidden true currents that are physically possible: the datasheet's current order, kept.

The simulated node hides per-DIMM currents of the form "datasheet × a ratio in [0.35, 0.85]". Drawn
independently per current, such ratios break the order every real device has (IDD3N below IDD2N,
IDD0 below IDD3N, ...), so some of the model's per-command energies turn negative and DDR "above
baseline" went negative in the demo. Here the ratios scale the datasheet's *increments* instead,
for each supply (``idd``/``ipp``):

    I2N = r·I2N_ds                     I3N = I2N + r·(I3N_ds − I2N_ds)
    IX  = I3N + r·(IX_ds − I3N_ds)     for IX in I0, I4R, I4W, I5B, I5F2, I5F4 (when IX_ds ≥ I3N_ds)
    I2P = I2P_ds·I2N/I2N_ds            I3P = I3P_ds·I3N/I3N_ds           other currents: r·I_ds

Each current is a weighted mean of ratios, so truth/datasheet stays in [0.35, 0.85], and every rule
of :mod:`hdeem_watch.dram.memspec_check` that the datasheet meets, the truth meets too (ρ = 1, Iβ = I0).
The result is split into a *floor* (the standby current a command current sits on) and an
*increment*, so that temperature can scale the background (floor) more than the command increment
without ever reordering the currents.

Example:
    >>> import numpy as np
    >>> names = ("idd0", "idd2n", "idd3n")
    >>> floor, inc = truth_parts(names, np.array([0.10, 0.05, 0.08]), np.array([[0.4, 0.8, 0.4]]))
    >>> [round(float(x), 4) for x in (floor + inc)[0]]   # IDD0 ≥ IDD3N ≥ IDD2N although r(IDD2N) is high
    [0.06, 0.04, 0.052]
"""

from __future__ import annotations

import numpy as np

#: Command currents, which sit on the active standby current of their supply.
_ON_ACTIVE_STANDBY = ("0", "4r", "4w", "5b", "5f2", "5f4")


def truth_parts(names: tuple[str, ...], datasheet: np.ndarray, ratio: np.ndarray,
                background: tuple[str, ...] = ()) -> tuple[np.ndarray, np.ndarray]:
    """Per-DIMM true currents as (floor, increment); their sum is the truth at 40 °C, age 0.

    Args:
        names: current names (lower case, as :data:`hdeem_watch.dram.energy.CURRENT_NAMES`).
        datasheet: datasheet currents, shape ``(len(names),)`` (A per device).
        ratio: truth/datasheet ratio per DIMM and current, shape ``(dimms, len(names))``.
        background: names counted wholly as floor (standby, refresh, power-down, self-refresh);
            the other currents are wholly increment unless they sit on active standby.

    Returns:
        ``(floor, increment)``, each ``(dimms, len(names))``, both >= 0.
    """
    ds = np.asarray(datasheet, dtype=float)
    r = np.asarray(ratio, dtype=float)
    index = {n: i for i, n in enumerate(names)}
    total = ds[None, :] * r
    floor = np.zeros_like(total)
    on_standby: set[int] = set()
    for prefix in ("idd", "ipp"):
        i2n, i3n = index.get(f"{prefix}2n"), index.get(f"{prefix}3n")
        if i2n is None or i3n is None:
            continue
        if ds[i3n] >= ds[i2n]:
            total[:, i3n] = total[:, i2n] + r[:, i3n] * (ds[i3n] - ds[i2n])
        for suffix in _ON_ACTIVE_STANDBY:
            j = index.get(f"{prefix}{suffix}")
            if j is not None and ds[j] >= ds[i3n]:
                total[:, j] = total[:, i3n] + r[:, j] * (ds[j] - ds[i3n])
                floor[:, j] = total[:, i3n]
                on_standby.add(j)
        for low, high in (("2p", i2n), ("3p", i3n)):
            j = index.get(f"{prefix}{low}")
            if j is not None and ds[high] > 0:
                total[:, j] = ds[j] * total[:, high] / ds[high]
    for name, j in index.items():
        if name in background and j not in on_standby:
            floor[:, j] = total[:, j]
    return floor, total - floor
