"""Physically consistent limits for the calibrated currents: bounds, and rules between two of them.

A real device draws its currents in an order (:mod:`hdeem_watch.dram.memspec_check`): IDD3N ≥
IDD2N ≥ IDD2P, IDD3N ≥ IDD3P, IDD4R/IDD4W ≥ IDD3N, refresh ≥ IDD3N, IDD0 above the tRAS/tRC mix
of IDD3N and IDD2N, and the activation and precharge increments ≥ 0. Each rule is a linear form
in the currents, ``Σ c_name · I_name ≥ 0`` (:func:`ordering_rules`). Against a set of calibrated
currents (:func:`physical_limits`) a rule is

- a **bound** when one calibrated current is in it (the others keep their memspec values):
  calibrating the default five currents, IDD2N ≥ IDD2P, IDD3N ≥ IDD3P and IDD3N ≤ IDD5B;
- a **coupling** when two or more are (IDD3N ≥ IDD2N, IDD4R ≥ IDD3N, IDD0 ≥ the mix, ...): a
  linear inequality the solver keeps when asked (``FitOptions(rules=True)``, ``calibrate
  --physical-rules``; :func:`hdeem_watch.calibrate.solve.solve_bounded`), so the calibrated
  memspec never charges a command a negative energy. By default a fit gives *effective* currents
  that may break couplings (real calibrations do: docs/calibration.md).

A rule against a current the data never uses does not apply (see :func:`physical_limits`).
:func:`fit_violations` checks a finished fit against the full rule set.

Example:
    >>> spec = type("Spec", (), {"currents": {"idd2n": 0.036, "idd2p": 0.017, "idd3n": 0.042,
    ...                                       "idd3p": 0.0225, "idd0": 0.0585}})()
    >>> physical_bounds(spec, ("idd2n", "idd0"))
    {'idd2n': (0.017, 0.042), 'idd0': (0.042, inf)}
    >>> [c.rule for c in physical_limits(spec, ("idd2n", "idd3n", "idd0")).couplings]
    ['activation', 'precharge', 'background']
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass

from hdeem_watch.calibrate.observation import SpecLike


@dataclass(frozen=True)
class OrderingRule:
    """One rule of a real device's current order: ``Σ coefficients[name] · I_name ≥ 0`` (amperes).

    Attributes:
        rule: what the rule protects (``activation``, ``read``, ``background``, ...).
        coefficients: per current (lower-case memspec name), its factor in the form.
    """

    rule: str
    coefficients: Mapping[str, float]


@dataclass(frozen=True)
class Coupling:
    """A rule between calibrated currents: ``Σ_j coefficients[j] · I_chosen[j] ≥ floor_a``.

    Attributes:
        rule: the :class:`OrderingRule` it comes from.
        coefficients: one per calibrated current, in the order they were chosen.
        floor_a: what the currents not calibrated contribute, moved to the right-hand side.
    """

    rule: str
    coefficients: tuple[float, ...]
    floor_a: float


@dataclass(frozen=True)
class PhysicalLimits:
    """The rules against a set of calibrated currents: per-current bounds and couplings.

    Attributes:
        bounds: per calibrated current ``(lower_a, upper_a)`` (``0`` / ``inf`` where no rule applies).
        couplings: the rules with two or more calibrated currents in them.
    """

    bounds: dict[str, tuple[float, float]]
    couplings: tuple[Coupling, ...]


def _refresh_current(spec: SpecLike) -> str:
    names = getattr(spec, "refresh_currents", None)
    return str(names[0]) if names else "idd5b"


def _supply_rules(spec: SpecLike, prefix: str) -> list[OrderingRule]:
    """The rules of one supply (``idd`` or ``ipp``) whose currents the memspec has."""
    cur = spec.currents
    i0, i2n, i3n = f"{prefix}0", f"{prefix}2n", f"{prefix}3n"
    if not {i0, i2n, i3n} <= set(cur):
        return []
    beta = "ibeta_vdd" if prefix == "idd" else "ibeta_vpp"
    beta = beta if beta in cur else i0
    timings = getattr(spec, "timings", None) or {}
    ras, rp = float(timings.get("RAS", 0) or 0), float(timings.get("RP", 0) or 0)
    rho = float(getattr(spec, "fact_rho", 1.0))
    banks = max(1, int(getattr(spec, "nbr_of_banks", 1) or 1))
    rules: list[OrderingRule] = []

    def rule(name: str, *terms: tuple[str, float]) -> None:
        form: dict[str, float] = {}
        for current, factor in terms:
            form[current] = form.get(current, 0.0) + factor
        form = {c: f for c, f in form.items() if f != 0.0}
        if len(form) > 1 and set(form) <= set(cur):
            rules.append(OrderingRule(name, form))

    # activation: I_theta >= I1, I_theta = (I0 (RP + RAS) - I_beta RP) / RAS, I1 = (I3N + (B-1) I_rho) / B
    one = (i3n, -(1.0 + (banks - 1) * rho) / banks), (i2n, -(banks - 1) * (1.0 - rho) / banks)
    if beta == i0:
        rule("activation", (i0, 1.0), *one)
    elif ras > 0:
        rule("activation", (i0, (rp + ras) / ras), (beta, -rp / ras), *one)
    rule("precharge", (beta, 1.0), (i2n, -1.0))
    if ras + rp > 0:
        rule("ACT+PRE", (i0, 1.0), (i3n, -ras / (ras + rp)), (i2n, -rp / (ras + rp)))
    rule("read", (f"{prefix}4r", 1.0), (i3n, -1.0))
    rule("write", (f"{prefix}4w", 1.0), (i3n, -1.0))
    refresh = _refresh_current(spec) if prefix == "idd" else (getattr(spec, "refresh_currents", None) or
                                                             ("", "ipp5b"))[1]
    rule("refresh", (refresh, 1.0), (i3n, -1.0))
    rule("background", (i3n, 1.0), (i2n, -1.0))
    rule("power-down", (i2n, 1.0), (f"{prefix}2p", -1.0))
    rule("power-down", (i3n, 1.0), (f"{prefix}3p", -1.0))
    return rules


def ordering_rules(spec: SpecLike) -> list[OrderingRule]:
    """Every ordering rule of ``spec``'s currents (both supplies), each a linear form ``≥ 0``.

    Needs only ``currents``; ``timings`` (RAS, RP), ``fact_rho``, ``nbr_of_banks`` and
    ``refresh_currents`` are used when the memspec has them (a rule whose currents it lacks is left out).
    """
    return _supply_rules(spec, "idd") + _supply_rules(spec, "ipp")


def physical_limits(spec: SpecLike, chosen: Sequence[str], used: Collection[str] | None = None) -> PhysicalLimits:
    """The ordering rules against the calibrated currents ``chosen``: bounds and couplings.

    A rule against a current the data never uses (``used``: the currents whose energy column is
    not zero in any run) does not apply: when no run has power-down residency, say, the model
    books a DIMM's idle time as standby, so the fitted IDD2N is the *effective* idle current (the
    controller's power-down included) and may well lie below IDD2P.

    Args:
        spec: the memspec (its ``currents``; see :func:`ordering_rules`).
        chosen: the calibrated currents (lower-case names).
        used: the currents the data uses (None: all of them).
    """
    cur: Mapping[str, float] = spec.currents
    position = {name: j for j, name in enumerate(chosen)}
    bounds = {name: (0.0, math.inf) for name in chosen}
    couplings: list[Coupling] = []
    for rule in ordering_rules(spec):
        mine = {c: f for c, f in rule.coefficients.items() if c in position}
        others = {c: f for c, f in rule.coefficients.items() if c not in position}
        if not mine or (used is not None and any(c not in used for c in others)):
            continue
        floor = -sum(f * float(cur[c]) for c, f in others.items())
        if len(mine) == 1:
            (name, factor), = mine.items()
            lo, hi = bounds[name]
            limit = floor / factor
            bounds[name] = (max(lo, limit), hi) if factor > 0 else (lo, min(hi, limit))
        else:
            coefficients = [0.0] * len(chosen)
            for name, factor in mine.items():
                coefficients[position[name]] = factor
            couplings.append(Coupling(rule.rule, tuple(coefficients), floor))
    return PhysicalLimits(bounds=bounds, couplings=tuple(couplings))


def physical_bounds(spec: SpecLike, chosen: Sequence[str],
                    used: Collection[str] | None = None) -> dict[str, tuple[float, float]]:
    """Per calibrated current, ``(lower_a, upper_a)`` implied by the ordering rules against the
    currents that are *not* calibrated (``0`` / ``inf`` where no rule applies); see
    :func:`physical_limits`, which also gives the rules between calibrated currents."""
    return physical_limits(spec, chosen, used).bounds


def fit_violations(spec: SpecLike, calibrated: Mapping[str, float]) -> list[str]:
    """The ordering rules the memspec with the ``calibrated`` currents breaks (empty: physical, or
    ``spec`` is not a full memspec and cannot be checked)."""
    from hdeem_watch.dram.memspec import MemSpec
    from hdeem_watch.dram.memspec_check import physical_violations

    if not isinstance(spec, MemSpec):
        return []
    return physical_violations(spec.with_currents(calibrated))
