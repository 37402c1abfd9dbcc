"""Physically consistent limits for the calibrated currents, and what a fit still breaks.

A real device draws its currents in an order (:mod:`hdeem_watch.dram.memspec_check`): IDD3N ≥
IDD2N ≥ IDD2P, IDD3N ≥ IDD3P, IDD4R/IDD4W ≥ IDD3N, refresh ≥ IDD3N, IDD0 above the tRAS/tRC mix
of IDD3N and IDD2N. The fit's solver takes box bounds only, so a rule becomes a bound where one
side of it is a current the fit does *not* calibrate (it keeps its memspec value): calibrating the
default five currents, IDD2N ≥ IDD2P, IDD3N ≥ IDD3P and IDD3N ≤ IDD5B become bounds. A rule between
two calibrated currents (IDD3N ≥ IDD2N, IDD4R ≥ IDD3N, ...) is not a box: the fit can break it, and
:func:`fit_violations` says so (``calibrate`` then warns and marks the memspec it writes).

Example:
    >>> spec = type("Spec", (), {"currents": {"idd2n": 0.036, "idd2p": 0.017, "idd3n": 0.042,
    ...                                       "idd3p": 0.0225, "idd0": 0.0585}})()
    >>> physical_bounds(spec, ("idd2n", "idd0"))
    {'idd2n': (0.017, 0.042), 'idd0': (0.042, inf)}
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping, Sequence

from hdeem_watch.calibrate.observation import SpecLike


def _refresh_current(spec: SpecLike) -> str:
    names = getattr(spec, "refresh_currents", None)
    return str(names[0]) if names else "idd5b"


def physical_bounds(spec: SpecLike, chosen: Sequence[str],
                    used: Collection[str] | None = None) -> dict[str, tuple[float, float]]:
    """Per calibrated current, ``(lower_a, upper_a)`` implied by the ordering rules against the
    currents that are *not* calibrated (``0`` / ``inf`` where no rule applies).

    A rule against a current the data never uses (``used``: the currents whose energy column is
    not zero in any run) does not apply: when no run has power-down residency, say, the model
    books a DIMM's idle time as standby, so the fitted IDD2N is the *effective* idle current (the
    controller's power-down included) and may well lie below IDD2P.

    Args:
        spec: the memspec (its ``currents``; ``timings``, ``fact_rho`` and ``refresh_currents``
            when it has them, as a :class:`~hdeem_watch.dram.memspec.MemSpec` does).
        chosen: the calibrated currents (lower-case names).
        used: the currents the data uses (None: all of them).
    """
    cur: Mapping[str, float] = spec.currents
    free = set(chosen)

    def fixed(name: str) -> float | None:
        value = cur.get(name)
        unused = used is not None and name not in used
        return None if name in free or value is None or unused else float(value)

    def most(*values: float | None) -> float:
        return max((v for v in values if v is not None), default=0.0)

    def least(*values: float | None) -> float:
        return min((v for v in values if v is not None), default=math.inf)

    beta = cur.get("ibeta_vdd")
    beta_fixed = float(beta) if beta is not None else fixed("idd0")
    timings = getattr(spec, "timings", None) or {}
    ras, rp = float(timings.get("RAS", 0) or 0), float(timings.get("RP", 0) or 0)
    rho = float(getattr(spec, "fact_rho", 1.0))
    i2n, i3n = fixed("idd2n"), fixed("idd3n")
    mix = (i3n * ras + i2n * rp) / (ras + rp) if i2n is not None and i3n is not None and ras + rp > 0 else None
    activation = i3n if i3n is not None and rho == 1.0 and beta is None else None
    out: dict[str, tuple[float, float]] = {}
    for name in chosen:
        if name == "idd2n":
            out[name] = (most(fixed("idd2p")), least(i3n, beta_fixed))
        elif name == "idd3n":
            out[name] = (most(fixed("idd3p"), i2n),
                         least(fixed("idd4r"), fixed("idd4w"), fixed(_refresh_current(spec)),
                               fixed("idd0") if rho == 1.0 and beta is None else None))
        elif name in ("idd4r", "idd4w") or name == _refresh_current(spec):
            out[name] = (most(i3n), math.inf)
        elif name == "idd0":
            out[name] = (most(mix, activation, i2n if beta is None else None), math.inf)
        elif name in ("idd2p", "idd3p"):
            out[name] = (0.0, least(i2n if name == "idd2p" else i3n))
        else:
            out[name] = (0.0, math.inf)
    return out


def fit_violations(spec: SpecLike, calibrated: Mapping[str, float]) -> list[str]:
    """The ordering rules the memspec with the ``calibrated`` currents breaks (empty: physical, or
    ``spec`` is not a full memspec and cannot be checked)."""
    from hdeem_watch.dram.memspec import MemSpec
    from hdeem_watch.dram.memspec_check import physical_violations

    if not isinstance(spec, MemSpec):
        return []
    return physical_violations(spec.with_currents(calibrated))
