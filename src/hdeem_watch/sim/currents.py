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

:class:`PartCurrents` holds the node's hidden per-DIMM currents over sim time: each DIMM *pair* is
a part of its own (a factor in ``1 ± part_spread`` on its ratios), each DIMM varies a little more
(``1 ± dimm_spread`` per current), temperature scales floor and increment differently, and a pair
can age (:mod:`hdeem_watch.sim.age`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from hdeem_watch.sim.age import age_factor

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


#: Currents whose temperature coefficient is the larger (standby, refresh, power-down).
BACKGROUND = ("idd2n", "idd3n", "idd2p", "idd3p", "idd6n", "idd5b", "ipp2n", "ipp3n", "ipp5b", "ipp6n")


class PartCurrents:
    """Hidden per-DIMM currents (A per device): datasheet × seeded ratios, per pair a part, with aging and heat.

    Ratios: a base ratio per current drawn in [0.35, 0.70] (the seed paper's calibrated/datasheet
    ratios for this module are 0.35–0.58, VAMPIRE's for DDR3 0.43–0.83), times a factor per DIMM
    pair in ``1 ± part_spread`` (the pair's part), times a factor per DIMM and current in
    ``1 ± dimm_spread``, clipped to [0.35, 0.85]; the ratios scale the datasheet's increments so the
    truth keeps its physical order (:func:`truth_parts`). Temperature of DIMM d:
    ``ambient_c + temp_amp_c × sin(2π t / 1 h + φ_d)``; background currents and the standby floor of
    command currents × (1 + 0.5 %/K (T − 40)), command increments × (1 + 0.1 %/K (T − 40)). Aging:
    every current × (1 + ``aging_per_h`` × hours) × the pair's own factor (``age``, ``age_start_s``).

    Args:
        names: current names.
        datasheet: datasheet currents (A per device).
        seed: the node's seed.
        aging_per_h: relative growth of every DIMM's currents per sim hour.
        temp_amp_c: amplitude of the temperature swing (°C, period 1 sim hour).
        dimm_spread: relative spread per DIMM and current.
        dimms: DIMMs (used when ``pairs`` is not given: DIMMs 2k, 2k+1 form pair k).
        part_spread: relative spread of the parts, one factor per pair.
        pairs: the sensor (pair) of each DIMM.
        age: ``{pair: relative growth per sim hour}`` of the pairs that age.
        age_start_s: ``{pair: sim s}`` when each pair's drift starts (default 0).
        ambient_c: the DIMMs' mean temperature (°C).

    Example:
        >>> import numpy as np
        >>> p = PartCurrents(("idd2n", "idd3n"), np.array([0.05, 0.08]), 1, dimms=4, age={"P1": 0.3},
        ...                  pairs=("P0", "P0", "P1", "P1"), temp_amp_c=0.0)
        >>> [round(float(x), 3) for x in p.currents(3600.0)[:, 0] / p.currents(0.0)[:, 0]]
        [1.0, 1.0, 1.3, 1.3]
    """

    def __init__(self, names: tuple[str, ...], datasheet: np.ndarray, seed: int, *, aging_per_h: float = 0.0,
                 temp_amp_c: float = 3.0, dimm_spread: float = 0.03, dimms: int = 8, part_spread: float = 0.10,
                 pairs: Sequence[str] | None = None, age: Mapping[str, float] | None = None,
                 age_start_s: Mapping[str, float] | None = None, ambient_c: float = 40.0) -> None:
        self.pairs = tuple(pairs) if pairs is not None else tuple(f"P{d // 2}" for d in range(dimms))
        dimms = len(self.pairs)
        rng = np.random.default_rng([int(seed), 7919])
        base = rng.uniform(0.35, 0.70, size=len(names))
        per_dimm = rng.uniform(1.0 - dimm_spread, 1.0 + dimm_spread, size=(dimms, len(names)))
        self.phase = rng.uniform(0.0, 2 * math.pi, size=dimms)
        part_rng = np.random.default_rng([int(seed), 6151])
        pair_names = tuple(dict.fromkeys(self.pairs))
        self.part_factor = dict(zip(pair_names, part_rng.uniform(1.0 - part_spread, 1.0 + part_spread,
                                                                 size=len(pair_names)).tolist()))
        per_pair = np.array([self.part_factor[p] for p in self.pairs])[:, None]
        self.names = names
        self.datasheet = np.asarray(datasheet, dtype=float)
        self.ratio = np.clip(base[None, :] * per_pair * per_dimm, 0.35, 0.85)
        self.aging_per_h = float(aging_per_h)
        self.temp_amp_c = float(temp_amp_c)
        self.ambient_c = float(ambient_c)
        self.age = dict(age or {})
        self.age_start_s = {p: float((age_start_s or {}).get(p, 0.0)) for p in self.age}
        self._floor, self._increment = truth_parts(names, self.datasheet, self.ratio, BACKGROUND)

    def temperature_c(self, t_s: float) -> np.ndarray:
        """DIMM temperatures (°C) at ``t_s`` seconds of sim time."""
        return self.ambient_c + self.temp_amp_c * np.sin(2 * math.pi * t_s / 3600.0 + self.phase)

    def age_factors(self, t_s: float) -> dict[str, float]:
        """Each aging pair's factor on its currents at ``t_s`` (pairs that do not age: absent)."""
        return {p: age_factor(rate, self.age_start_s[p], t_s) for p, rate in self.age.items()}

    def currents(self, t_s: float) -> np.ndarray:
        """True currents (A per device), shape (DIMMs, len(names)), at ``t_s`` seconds of sim time."""
        aging = np.full((len(self.pairs), 1), 1.0 + self.aging_per_h * t_s / 3600.0)
        if self.age:
            factors = self.age_factors(t_s)
            aging *= np.array([[factors.get(p, 1.0)] for p in self.pairs])
        warm = (self.temperature_c(t_s) - 40.0)[:, None]
        return (self._floor * (1.0 + 0.005 * warm) + self._increment * (1.0 + 0.001 * warm)) * aging
