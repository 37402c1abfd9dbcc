"""Intervals that carry what the rows do not know (pure): held standby currents, kinds, command models.

A fit's analytic interval (:mod:`hdeem_watch.calibrate.fit`) assumes the rows are right and only the
measurements are noisy. On a real node (and on the simulated one) they are not, in three ways this
module puts into the reported interval and the verdict "determined":

- **A current without a state of its own.** With counted commands on a controller that powers
  idle ranks down, almost no window holds precharged standby: IDD2N is seen only through the
  activation energy (``IDD0·tRC − IDD3N·tRAS − IDD2N·(tRC − tRAS)``), where it trades with IDD0.
  Such a current (not determined by the base fit) is **held** at its datasheet value scaled like its
  anchor (IDD2N like IDD3N: one die, one process corner), reported as not determined with its
  plausible range (its lower bound or the calibrated IDD2P, up to the anchor: IDD2P ≤ IDD2N ≤ IDD3N),
  and the currents it trades with are refitted at both ends of that range: their interval spans the
  two answers.
- **Mixed standby.** DDR5's active standby is ``ρ·IDD3N + (1 − ρ)·IDD2N`` (DRAMPower's DDR5 test
  memspec: ρ = 0.5), and a counted busy window is almost all active standby: both currents appear
  in every row in one fixed mix, so the base fit determines neither and the anchor rule above
  cannot hold IDD2N. The current is then **tied** to its anchor at their datasheet ratio (its column
  folded into the anchor's); where that fit determines the anchor, the current is held at the
  ratio times the anchor (the hold's fixed point), and its range is the part of
  ``[IDD2P, IDD3N]`` the rows do not reject: a refit at each of :data:`PROFILE_STEPS` values, kept
  while its residual sum of squares stays within ``1 + F₀.₉₅(1, G − k)/(G − k)`` of the best
  (``G`` kinds of run, ``k`` unknowns: the kinds are the independent data). The other currents are
  refitted at both ends of that range, as above; the anchor, whose split from the current the rows
  do not see, is then rarely determined.
- **Systematic misfit per kind of run.** The residuals of one kind of run (kernel × threads) share a
  model error, so runs are not independent draws. A delete-one-kind jackknife over the kinds
  (``kind`` = the run name after ``"r<n>:"``) gives each current's spread when one kind is left out;
  its standard error, ``√((G−1)/G·Σ(θ_g − θ̄)²)``, is combined with the analytic half-width in
  quadrature (t quantile with ``G − 1`` degrees of freedom).
- **Modelled commands nothing confirms.** A row from the kernel model has activations (and their
  precharges) from an assumed page placement and address mapping: on the simulated node the counted
  ACTs per kind are 0.4–11× the model's (median 53 % off). For rows whose commands are modelled
  (:attr:`Observation.commands` ``"model"`` with their ``act_columns``), the fit is repeated over
  ``draws`` mappings: a factor common to every kind (the node's one mapping; evenly over
  ``[1/act_factor, act_factor]`` on a log scale) times a factor per kind of run (log-uniform in
  ``[1/kind_factor, kind_factor]``) scales each row's ACT/PRE columns; the 2.5–97.5 % range of the
  answers joins the interval. The common factor and IDD0 are not separable (only their product
  shows in the energies), so without counters IDD0 — and the currents it trades with — are
  determined only as far as that factor is known. Counted rows are not perturbed.

A current is then **determined** when the base fit says so and the final 95 % half-width is at most
``FitSettings.max_rel_ci`` of its value. Everything is a refit of the same bounded problem (no
analytic shortcut), with leave-one-out off in the extra refits.

Example:
    >>> import numpy as np
    >>> from hdeem_watch.calibrate.fit import FitOptions
    >>> from hdeem_watch.calibrate.observation import Observation
    >>> class Spec:
    ...     currents = {"a": 1.0, "b": 1.0}
    >>> rng = np.random.default_rng(0)
    >>> rows = [Observation(f"r{i}:k{i % 6}", np.array([x, 1.0]), 0.0, x * 0.5 + 0.8 + 0.005 * rng.normal())
    ...         for i, x in enumerate(rng.uniform(1, 3, 30))]
    >>> result = trusted_fit(rows, Spec(), FitOptions(currents=("a", "b"), names=("a", "b"), intercept=False),
    ...                      trust=TrustOptions())
    >>> [round(float(v), 2) for v in result.calibrated_a], result.trust["kinds"]
    ([0.5, 0.8], 6)
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hdeem_watch.calibrate.fit import FitOptions, fit
from hdeem_watch.calibrate.observation import Observation, SpecLike, current_names
from hdeem_watch.calibrate.result import FitResult
from hdeem_watch.errors import InputError

#: A current without a state of its own → the current it is scaled like when held.
DEFAULT_ANCHORS: Mapping[str, str] = {"idd2n": "idd3n"}
#: The current whose calibrated value is the lower end of a held current's plausible range.
RANGE_FLOOR: Mapping[str, str] = {"idd2n": "idd2p", "idd3n": "idd3p"}
#: A kind's free activation factor as a pseudo-current: 1 = the model's ACT energy at the datasheet
#: is this many amperes (its bound, 1 A, is then 100× that energy).
_UNIT = 0.01
#: Fewest kinds of run for the jackknife (fewer: the analytic interval only).
MIN_KINDS = 5
#: Values of a tied current over its plausible range at which the rows' rejection is tested.
PROFILE_STEPS = 9


@dataclass(frozen=True)
class TrustOptions:
    """How :func:`trusted_fit` widens the intervals (module docstring).

    Attributes:
        anchors: current → anchor for holding a current the base fit does not determine.
        jackknife: delete-one-kind jackknife over the kinds of run.
        act_factor: the modelled rows' activation counts are uncertain by this factor, common to
            every kind (one node, one page placement and address mapping; 1: off).
        kind_factor: ... and by this factor more per kind of run (how the mapping meets each
            access pattern).
        draws: mappings for the modelled rows (the common factor evenly over its log range).
        seed: their seed.
    """

    anchors: Mapping[str, str] = field(default_factory=lambda: dict(DEFAULT_ANCHORS))
    jackknife: bool = True
    act_factor: float = 3.0
    kind_factor: float = 4.0
    draws: int = 16
    seed: int = 0

    def __post_init__(self) -> None:
        if not (self.act_factor >= 1.0 and self.kind_factor >= 1.0) or self.draws < 0:
            raise InputError(f"trust: act_factor = {self.act_factor!r}, kind_factor = {self.kind_factor!r}, "
                             f"draws = {self.draws!r}; expected factors >= 1 and draws >= 0")


def run_kind(name: str) -> str:
    """The kind of a run from its name: the part after the run id (``"r12:read-24t"`` → ``"read-24t"``)."""
    return str(name).split(":", 1)[-1]


class _HeldSpec:
    """A memspec view with some currents replaced (the fit reads only ``currents``)."""

    def __init__(self, spec: SpecLike, held: Mapping[str, float]) -> None:
        self.base = spec
        self.currents = {**dict(spec.currents), **dict(held)}

    def __getattr__(self, name: str) -> Any:
        return getattr(self.base, name)


def _quiet(options: FitOptions) -> FitOptions:
    """The options of the extra refits: no leave-one-out, analytic intervals, any number of runs (a
    refit with fewer runs than unknowns answers, and its intervals say so)."""
    return dataclasses.replace(options, loo="none", uncertainty="analytic", require_overdetermined=False)


def _held_values(base: FitResult, spec: SpecLike, anchors: Mapping[str, str],
                 lower: Mapping[str, float]) -> dict[str, float]:
    """Held current → its datasheet value scaled like its anchor (only where the base fit leaves it
    undetermined and determines the anchor)."""
    out = {}
    for current, anchor in anchors.items():
        if current not in base.currents or anchor not in base.currents:
            continue
        j, a = base.currents.index(current), base.currents.index(anchor)
        if base.identifiable[j] or not base.identifiable[a] or not base.datasheet_a[a] > 0:
            continue
        value = float(spec.currents.get(current, 0.0)) * float(base.calibrated_a[a]) / float(base.datasheet_a[a])
        out[current] = max(value, lower.get(current, 0.0))
    return out


def _tied_values(base: FitResult, rows: Sequence[Observation], spec: SpecLike, options: FitOptions,
                 weights: np.ndarray | None, anchors: Mapping[str, str],
                 lower: Mapping[str, float]) -> dict[str, float]:
    """Held current → its value when the base fit determines neither it nor its anchor (module
    docstring, *mixed standby*): the fit with the current tied to its anchor at their datasheet ratio
    (its column folded into the anchor's), kept where that fit determines the anchor."""
    out: dict[str, float] = {}
    names = tuple(options.names) if options.names is not None else tuple(current_names(spec))
    for current, anchor in anchors.items():
        if current not in base.currents or anchor not in base.currents or current in out:
            continue
        j, a = base.currents.index(current), base.currents.index(anchor)
        ratio = float(spec.currents.get(current, 0.0)) / float(base.datasheet_a[a]) if base.datasheet_a[a] > 0 else 0.0
        if base.identifiable[j] or base.identifiable[a] or not ratio > 0:
            continue
        jc, ja = names.index(current), names.index(anchor)
        tied = []
        for row in rows:
            columns = row.columns.copy()
            columns[ja] += ratio * columns[jc]
            columns[jc] = 0.0
            tied.append(dataclasses.replace(row, columns=columns))
        currents = tuple(c for c in options.currents if c.lower() != current)
        try:
            result = fit(tied, spec, dataclasses.replace(_quiet(options), currents=currents), weights=weights)
        except InputError:
            continue
        if result.determined(anchor):
            out[current] = max(ratio * float(result.calibrated[anchor]), lower.get(current, 0.0))
    return out


def _rss(result: FitResult) -> float:
    """The fit's weighted sum of squared relative residuals."""
    return float(result.noise_rel) ** 2 * max(int(result.dof), 1)


def _unrejected(rows: Sequence[Observation], spec: SpecLike, options: FitOptions, weights: np.ndarray | None,
                held: Mapping[str, float], current: str, span: tuple[float, float], kinds: int,
                steps: int = PROFILE_STEPS) -> tuple[float, float]:
    """The part of ``span`` whose values of the held ``current`` the rows do not reject: a refit with
    the current fixed at each of ``steps`` values over the span, kept while its residual sum of
    squares stays within the F test's 95 % bound of the best (``F(1, kinds − unknowns)``: the runs of
    one kind share their model error, so the kinds are the independent data), the best taken at no
    less than the fit's noise floor."""
    from scipy.special import fdtri

    values = np.linspace(span[0], span[1], steps)
    rss = []
    for v in values:
        try:
            rss.append(_rss(_fit_held(rows, spec, _quiet(options), weights, {**held, current: float(v)}, 0)))
        except InputError:
            rss.append(math.inf)
    central = _fit_held(rows, spec, _quiet(options), weights, held, 0)
    # at least the noise the fit assumes of any sensor (FitSettings.noise_floor): an exact fit rejects nothing
    best = max(float(min([*rss, _rss(central)])), options.settings.noise_floor ** 2 * max(int(central.dof), 1))
    dof = max(1, kinds - len(options.currents))
    limit = best * (1.0 + float(fdtri(1, dof, 0.95)) / dof)
    kept = [float(v) for v, r in zip(values, rss, strict=True) if r <= limit] + [float(held[current])]
    return min(kept), max(kept)


def _fit_held(rows: Sequence[Observation], spec: SpecLike, options: FitOptions, weights: np.ndarray | None,
              held: Mapping[str, float], time_ns: int) -> FitResult:
    currents = tuple(c for c in options.currents if c.lower() not in held)
    return fit(rows, _HeldSpec(spec, held) if held else spec, dataclasses.replace(options, currents=currents),
               weights=weights, time_ns=time_ns)


def _values(result: FitResult, names: Sequence[str], held: Mapping[str, float]) -> np.ndarray:
    cal = result.calibrated
    return np.array([held[n] if n in held else cal.get(n, math.nan) for n in names])


def _jackknife_sd(rows: Sequence[Observation], spec: SpecLike, options: FitOptions, weights: np.ndarray | None,
                  held: Mapping[str, float], names: Sequence[str]) -> tuple[np.ndarray, int]:
    """Delete-one-kind jackknife standard error per current, and the number of kinds."""
    kinds = [run_kind(r.name) for r in rows]
    unique = sorted(set(kinds))
    if len(unique) < MIN_KINDS:
        return np.zeros(len(names)), len(unique)
    w = np.ones(len(rows)) if weights is None else np.asarray(weights, dtype=float)
    estimates = []
    for kind in unique:
        keep = [i for i, k in enumerate(kinds) if k != kind]
        sub = [rows[i] for i in keep]
        try:
            estimates.append(_values(_fit_held(sub, spec, _quiet(options), w[keep], held, 0), names, held))
        except InputError:
            continue
    if len(estimates) < MIN_KINDS:
        return np.zeros(len(names)), len(unique)
    theta = np.array(estimates)
    g = theta.shape[0]
    return np.sqrt((g - 1) / g * np.sum((theta - theta.mean(axis=0)) ** 2, axis=0)), len(unique)


def _command_range(rows: Sequence[Observation], spec: SpecLike, options: FitOptions, weights: np.ndarray | None,
                   held: Mapping[str, float], names: Sequence[str], trust: TrustOptions) -> np.ndarray | None:
    """2.5/97.5 % of the currents over random activation factors per kind of the modelled rows."""
    modelled = [i for i, r in enumerate(rows) if r.commands == "model" and r.act_columns is not None]
    if not modelled or trust.act_factor <= 1.0 or trust.draws < 2:
        return None
    kinds = sorted({run_kind(rows[i].name) for i in modelled})
    rng = np.random.default_rng(trust.seed)
    log_g, log_k = math.log(trust.act_factor), math.log(trust.kind_factor)
    answers = []
    for d in range(trust.draws):  # the node's mapping: one factor for every kind, evenly over its range
        common = -log_g + 2.0 * log_g * d / (trust.draws - 1)
        factor = dict(zip(kinds, np.exp(common + rng.uniform(-log_k, log_k, len(kinds))), strict=True))
        drawn = list(rows)
        for i in modelled:
            row = rows[i]
            assert row.act_columns is not None
            f = float(factor[run_kind(row.name)])
            drawn[i] = dataclasses.replace(row, columns=row.columns + (f - 1.0) * row.act_columns)
        try:
            answers.append(_values(_fit_held(drawn, spec, _quiet(options), weights, held, 0), names, held))
        except InputError:
            continue
    widths = {len(rows[i].act_factors) for i in modelled} - {0}
    families = widths.pop() if len(widths) == 1 else 0
    for f in range(families):  # the other address-mapping families, each as a whole
        drawn = list(rows)
        for i in modelled:
            row = rows[i]
            assert row.act_columns is not None
            if row.act_factors:
                drawn[i] = dataclasses.replace(row, columns=row.columns + (row.act_factors[f] - 1.0) * row.act_columns)
        try:
            family = _values(_fit_held(drawn, spec, _quiet(options), weights, held, 0), names, held)
        except InputError:
            continue
        answers.extend([family, family])  # an envelope member, not a draw: inside the percentiles
    if len(answers) < 2:
        return None
    spread = np.array(answers)
    out = np.percentile(spread, [2.5, 97.5], axis=0).T
    if families:
        out = np.column_stack([spread[-2 * families:].min(axis=0).clip(max=out[:, 0]),
                               spread[-2 * families:].max(axis=0).clip(min=out[:, 1])])
    return out


def _act_free(rows: Sequence[Observation], spec: SpecLike, options: FitOptions, weights: np.ndarray | None,
              held: Mapping[str, float], names: Sequence[str]) -> FitResult | None:
    """The fit with each kind's modelled activation energy a free unknown ``≥ 0`` (None: no such rows).

    A modelled row's ACT/PRE columns are replaced by one column per kind of run: the model's
    activation energy at the datasheet currents, times an unknown factor ``u_kind ≥ 0``. What this
    fit still determines does not rest on the modelled activations.
    """
    all_names = tuple(options.names) if options.names is not None else tuple(current_names(spec))
    datasheet = np.array([float(spec.currents.get(n, 0.0)) for n in all_names])
    modelled = [i for i, r in enumerate(rows) if r.commands == "model" and r.act_columns is not None
                and float(r.act_columns @ datasheet) > 0]
    if not modelled:
        return None
    kinds = sorted({run_kind(rows[i].name) for i in modelled})
    extra = tuple(f"act:{k}" for k in kinds)
    position = {k: j for j, k in enumerate(kinds)}
    augmented = []
    for i, row in enumerate(rows):
        added = np.zeros(len(kinds))
        columns = row.columns
        if i in modelled:
            assert row.act_columns is not None
            columns = row.columns - row.act_columns
            added[position[run_kind(row.name)]] = float(row.act_columns @ datasheet) / _UNIT
        augmented.append(dataclasses.replace(row, columns=np.concatenate([columns, added]), act_columns=None,
                                             act_factors=()))
    spec_free = _HeldSpec(spec, {**dict(held), **dict.fromkeys(extra, _UNIT)})
    currents = tuple(c for c in options.currents if c.lower() not in held) + extra
    free_options = dataclasses.replace(_quiet(options), currents=currents, names=all_names + extra,
                                       bounds={**dict(options.bounds or {}), **dict.fromkeys(extra, (0.0, 1.0))})
    try:
        return fit(augmented, spec_free, free_options, weights=weights)
    except InputError:
        return None


def _unbounded_half(result: FitResult, name: str) -> float:
    """95 % half-width (A) of current ``name`` with every bound ignored, at the fit's own residual
    scale: a bound a free unknown sits at must not make a current look determined."""
    model = result.model
    if model is None or not math.isfinite(result.noise_rel):
        return math.inf
    j = result.currents.index(name)
    try:
        variance = float(np.linalg.inv(model.info)[j, j])
    except np.linalg.LinAlgError:
        return math.inf
    return 1.96 * result.noise_rel * math.sqrt(max(variance, 0.0)) * float(model.scales_a[j])


def _held_range(base: FitResult, current: str, anchor: str, lower: Mapping[str, float]) -> tuple[float, float]:
    floor_name = RANGE_FLOOR.get(current)
    cal = base.calibrated
    low = max(lower.get(current, 0.0), cal.get(floor_name, 0.0) if floor_name else 0.0)
    high = max(low, cal.get(anchor, low))
    return low, high


def trusted_fit(rows: Sequence[Observation], spec: SpecLike, options: FitOptions, *,
                weights: np.ndarray | None = None, time_ns: int = 0,
                trust: TrustOptions | None = None) -> FitResult:
    """``fit`` with the widened intervals and held currents of the module docstring.

    Returns:
        A :class:`FitResult` over ``options.currents``; held currents carry their held value and
        plausible range and are not determined; ``trust`` says what went into the intervals.
    """
    trust = trust or TrustOptions()
    base = fit(rows, spec, options, weights=weights, time_ns=time_ns)
    names = base.currents
    lower = {n: float(lo) for n, (lo, _hi) in (options.bounds or {}).items()}
    held, tied, central = _hold(base, rows, spec, options, weights, trust.anchors, lower, time_ns)
    value = _values(central, names, held)
    ci = np.array([central.interval(n) if n not in held else (math.nan, math.nan) for n in names],
                  dtype=float).reshape(len(names), 2)
    sd_kind, kinds = (_jackknife_sd(rows, spec, options, weights, held, names) if trust.jackknife
                      else (np.zeros(len(names)), 0))
    # scipy.special on first use (importing scipy.stats cost every process ~1 s of start-up CPU)
    from scipy.special import stdtrit

    t = float(stdtrit(max(1, kinds - 1), 0.975)) if kinds >= MIN_KINDS else 0.0  # the Student t quantile
    half = np.sqrt(np.nan_to_num(np.maximum(value - ci[:, 0], ci[:, 1] - value)) ** 2 + (t * sd_kind) ** 2)
    low, high = value - half, value + half
    commands = _command_range(rows, spec, options, weights, held, names, trust)
    if commands is not None:
        low, high = np.fmin(low, commands[:, 0]), np.fmax(high, commands[:, 1])
    free = _act_free(rows, spec, options, weights, held, names) if commands is not None else None
    unconfirmed = []
    if free is not None:
        for j, n in enumerate(names):
            if n in held or n not in free.currents:
                continue
            half_f = _unbounded_half(free, n)
            scale = max(abs(float(free.calibrated[n])), 0.05 * float(base.datasheet_a[j]))
            lo_f, hi_f = float(free.calibrated[n]) - half_f, float(free.calibrated[n]) + half_f
            if not half_f <= options.settings.max_rel_ci * scale:
                unconfirmed.append(n)
                lo_f, hi_f = 0.0, float(base.datasheet_a[j])
            low[j], high[j] = min(low[j], lo_f), max(high[j], hi_f)
    held_info = {}
    for current, v in held.items():
        anchor = trust.anchors[current]
        lo_h, hi_h = _held_range(central, current, anchor, lower)
        if current in tied:
            lo_h, hi_h = _unrejected(rows, spec, options, weights, held, current, (lo_h, hi_h),
                                     kinds or len({run_kind(r.name) for r in rows}))
        for end in (lo_h, hi_h):
            other = _values(_fit_held(rows, spec, _quiet(options), weights, {**held, current: end}, 0), names, held)
            low, high = np.fmin(low, other), np.fmax(high, other)
        j = names.index(current)
        low[j], high[j] = lo_h, hi_h
        held_info[current] = {"value": v, "anchor": anchor, "range": [lo_h, hi_h], "tied": current in tied}
    ci_out = np.column_stack([np.maximum(low, 0.0), high])
    reference = np.maximum(np.abs(value), 0.05 * base.datasheet_a)
    narrow = (ci_out[:, 1] - ci_out[:, 0]) / 2 <= options.settings.max_rel_ci * reference
    determined = np.array([n not in held and n not in unconfirmed and central.determined(n)
                           for n in names]) & narrow
    info = {"commands": commands_of(rows), "held": held_info, "kinds": kinds,
            "kind_sd_a": {n: float(s) for n, s in zip(names, sd_kind)},
            "act_factor": trust.act_factor if commands is not None else None,
            "draws": trust.draws if commands is not None else 0,
            "unconfirmed": unconfirmed}
    at_bound = tuple(None if n in held else central.at_bound[central.currents.index(n)] for n in names)
    return dataclasses.replace(central, currents=names, datasheet_a=base.datasheet_a, calibrated_a=value,
                               ci95_a=ci_out, identifiable=determined, at_bound=at_bound,
                               sensitivity=base.sensitivity, singular_values=base.singular_values,
                               condition_number=base.condition_number, rank=base.rank,
                               correlation=base.correlation, trust=info,
                               uncertainty=f"{central.uncertainty}+kinds+commands")


def _hold(base: FitResult, rows: Sequence[Observation], spec: SpecLike, options: FitOptions,
          weights: np.ndarray | None, anchors: Mapping[str, str], lower: Mapping[str, float],
          time_ns: int) -> tuple[dict[str, float], dict[str, float], FitResult]:
    """The held currents (module docstring), the tied ones among them, and the fit with them held."""
    held: dict[str, float] = {}
    central = base
    for _ in range(2):  # the anchor moves a little once the held current is fixed
        held = _held_values(base if not held else _merge(central, base, held), spec, anchors, lower)
        if not held:
            break
        central = _fit_held(rows, spec, options, weights, held, time_ns)
    tied = _tied_values(base, rows, spec, options, weights, anchors, lower) if not held else {}
    if tied:  # the tied fit's answer is the hold's fixed point: one refit with it held
        held = dict(tied)
        central = _fit_held(rows, spec, options, weights, held, time_ns)
    return held, tied, central


def _merge(central: FitResult, base: FitResult, held: Mapping[str, float]) -> FitResult:
    """``base`` with the calibrated values of ``central`` (the anchor after holding)."""
    value = np.array([central.calibrated.get(n, float(base.calibrated_a[j])) for j, n in enumerate(base.currents)])
    return dataclasses.replace(base, calibrated_a=value)


def commands_of(rows: Sequence[Observation]) -> str:
    """``"counted"``, ``"modelled"``, ``"mixed"`` or ``"unknown"``: where the rows' commands come from."""
    sources = {r.commands for r in rows}
    if sources == {"counters"}:
        return "counted"
    if sources == {"model"}:
        return "modelled"
    if sources <= {"counters", "model", ""} and {"counters", "model"} <= sources:
        return "mixed"
    return "unknown" if "" in sources and len(sources) == 1 else "mixed"


def carried(cheap: FitResult, full: FitResult) -> FitResult:
    """``cheap`` (a fit with held currents only: no jackknife, no mapping refits) with the interval
    widths — relative to each value — and the verdicts of ``full``, the latest fit that computed them
    (the online calibrator refreshes them every few runs; they change slowly once a fit has dozens of
    runs). ``trust.refreshed_runs`` says how many runs ``full`` had."""
    low, high, determined = [], [], []
    for j, name in enumerate(cheap.currents):
        value = float(cheap.calibrated_a[j])
        if name not in full.currents:
            low.append(float(cheap.ci95_a[j, 0]))
            high.append(float(cheap.ci95_a[j, 1]))
            determined.append(bool(cheap.identifiable[j]))
            continue
        k = full.currents.index(name)
        reference = float(full.calibrated_a[k])
        lo_f, hi_f = (float(v) for v in full.ci95_a[k])
        held = name in (full.trust or {}).get("held", {})
        unconfirmed = name in (full.trust or {}).get("unconfirmed", [])
        if held or unconfirmed or not reference > 0:
            low.append(lo_f)
            high.append(hi_f)
        else:
            low.append(max(0.0, value * lo_f / reference))
            high.append(value * hi_f / reference)
        determined.append(bool(full.identifiable[k]))
    info = {**dict(full.trust or {}), "held": dict((cheap.trust or {}).get("held", {})),
            "refreshed_runs": full.n_runs}
    return dataclasses.replace(cheap, ci95_a=np.column_stack([low, high]), identifiable=np.array(determined),
                               trust=info, uncertainty=full.uncertainty)
