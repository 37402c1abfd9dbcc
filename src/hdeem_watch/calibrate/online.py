"""Online calibration: refit as runs finish, forget old runs with a half-life, flag drift.

Pure: no I/O and no clock — time comes from the observations' ``time_ns``. The daemon persists the
state with :meth:`OnlineCalibrator.to_dict` / :meth:`OnlineCalibrator.from_dict`.

Forgetting: a run ``Δt`` older than the newest one weighs ``2^(−Δt/half_life)`` (times its own
weight); runs whose weight falls below ``min_weight`` are dropped, so memory stays bounded. Every
refit solves the bounded problem afresh on the weighted rows (a few hundred microseconds for
hundreds of runs, because the solve works on the QR factor), so bounds that start or stop holding
are handled exactly — an incremental rank-one update would have to give that up.

Drift: a current has drifted when the latest fit puts it outside the 95 % interval of the fit one
``drift_lag_s`` earlier (default: one half-life), both fits determining it.

Example::

    calib = OnlineCalibrator(spec, half_life_s=14 * 86400)
    for obs in finished_runs:
        result = calib.add_run(obs)
    calib.drift()   # {"idd0": False, "idd3n": True, ...}
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from hdeem_watch.calibrate.fit import FitOptions, fit
from hdeem_watch.calibrate.observation import DEFAULT_CURRENTS, Observation, SpecLike, current_names
from hdeem_watch.calibrate.result import FitResult, FitSettings
from hdeem_watch.calibrate.trust import TrustOptions, carried, trusted_fit
from hdeem_watch.errors import InputError

_STATE_VERSION = 1
#: A trusted calibrator computes its full intervals at every refit up to this many runs ...
TRUST_FULL_UNTIL = 64
#: ... and then every this many runs (carried in between).
TRUST_EVERY = 8


class OnlineCalibrator:
    """Keeps the runs, refits after each, and keeps the history of fits.

    Args:
        spec: the memspec (datasheet currents).
        currents: the currents to calibrate.
        half_life_s: age at which a run counts half; ``None`` or ``inf`` = never forget.
        bounds, intercept, prior_weight, settings: as for :func:`~hdeem_watch.calibrate.fit.fit`.
        names: the observation column order (default ``energy.CURRENT_NAMES``).
        min_weight: runs whose forgetting weight falls below this are dropped.
        max_runs: at most this many runs are kept (the oldest are dropped first).
        max_history: fits kept in :attr:`history` (oldest dropped first).
        drift_lag_s: how far back the reference fit of :meth:`drift` is (default half-life).
        loo: leave-one-out mode of each refit (``"hat"``: cheap).
        rules: keep the ordering rules between calibrated currents in each refit
            (:attr:`~hdeem_watch.calibrate.fit.FitOptions.rules`; may be changed between refits).
        trust: widen every refit's intervals and hold currents without a state of their own
            (:func:`~hdeem_watch.calibrate.trust.trusted_fit`); None: the plain fit.

    Example::

        calib = OnlineCalibrator(spec, half_life_s=14 * 86400)
        fit_now = calib.add_run(observation_from_run(spec, stats, window_s, measured_j, time_ns=t))
        state = calib.to_dict()                         # persist (JSON)
        calib = OnlineCalibrator.from_dict(state, spec) # after a restart
    """

    def __init__(self, spec: SpecLike, *, currents: Sequence[str] = DEFAULT_CURRENTS,
                 half_life_s: float | None = 30 * 86400.0,
                 bounds: Mapping[str, tuple[float, float]] | None = None, intercept: bool = True,
                 prior_weight: float = 0.0, settings: FitSettings | None = None,
                 names: Sequence[str] | None = None, min_weight: float = 1e-4, max_history: int = 256,
                 max_runs: int = 2000,
                 drift_lag_s: float | None = None, loo: str = "hat", rules: bool = False,
                 trust: TrustOptions | None = None) -> None:
        if half_life_s is not None and not (half_life_s > 0):
            raise InputError(f"half_life_s: {half_life_s!r}; expected a duration > 0 s (or None)")
        self.spec = spec
        self.currents = tuple(currents)
        self.half_life_s = None if half_life_s is None or math.isinf(half_life_s) else float(half_life_s)
        self.bounds = dict(bounds) if bounds else None
        self.intercept = intercept
        self.prior_weight = prior_weight
        self.settings = settings or FitSettings()
        self.names = tuple(names) if names is not None else current_names(spec)
        self.min_weight = min_weight
        self.max_runs = max_runs
        self.max_history = max_history
        self.drift_lag_s = drift_lag_s
        self.loo = loo
        self.rules = bool(rules)
        self.trust = trust
        self._full_trust: FitResult | None = None
        self._full_options: TrustOptions | None = None
        self._since_full = 0
        self.observations: list[Observation] = []
        self.history: list[tuple[int, FitResult]] = []
        self.latest: FitResult | None = None

    def fit_options(self) -> FitOptions:
        """The options of every refit (from this calibrator's settings; fits from the first run)."""
        return FitOptions(currents=self.currents, bounds=self.bounds, intercept=self.intercept,
                          prior_weight=self.prior_weight, loo=self.loo, names=self.names,
                          require_overdetermined=False, settings=self.settings, rules=self.rules)

    def weights(self) -> np.ndarray:
        """Forgetting factor of each kept run (1 for the newest)."""
        if not self.observations:
            return np.zeros(0)
        t = np.array([obs.time_ns for obs in self.observations], dtype=float)
        if self.half_life_s is None:
            return np.ones(t.size)
        return np.exp2(-(t.max() - t) / (self.half_life_s * 1e9))

    def add_run(self, obs: Observation) -> FitResult:
        """Add a finished run, drop forgotten ones, refit and record the fit.

        Raises:
            InputError: a row that does not match the model's columns.
        """
        if obs.columns.shape[0] != len(self.names):
            raise InputError(f"run {obs.name!r}: {obs.columns.shape[0]} model columns; expected {len(self.names)}")
        self.observations.append(obs)
        decay = self.weights()
        keep = decay >= self.min_weight
        if len(self.observations) > self.max_runs:
            order = np.argsort([o.time_ns for o in self.observations], kind="stable")
            keep[order[: len(self.observations) - self.max_runs]] = False
        if not keep.all():
            self.observations = [o for o, k in zip(self.observations, keep) if k]
            decay = decay[keep]
        return self._refit(decay)

    def refit(self) -> FitResult | None:
        """Refit on the kept runs (after a settings change), trusted intervals in full; records the fit."""
        self._full_trust = None
        return self._refit(self.weights()) if self.observations else None

    def _refit(self, decay: np.ndarray) -> FitResult:
        now = max(o.time_ns for o in self.observations)
        result = self._fit(decay, now)
        self.latest = result
        self.history.append((now, result))
        if len(self.history) > self.max_history:
            del self.history[: len(self.history) - self.max_history]
        return result

    def _fit(self, weights: np.ndarray, time_ns: int) -> FitResult:
        """The refit: plain, or :func:`trusted_fit` — in full while the fit is young and every
        :data:`TRUST_EVERY` runs after, in between its central fit with the last full intervals and
        verdicts carried (:func:`~hdeem_watch.calibrate.trust.carried`: a full one costs ~30–50 refits)."""
        if self.trust is None:
            return fit(self.observations, self.spec, self.fit_options(), weights=weights, time_ns=time_ns)
        last = self._full_trust
        self._since_full += 1
        if last is None or len(self.observations) <= TRUST_FULL_UNTIL or self._since_full >= TRUST_EVERY or \
                set(last.currents) != set(self.currents) or self._full_options is not self.trust:
            self._full_options, self._since_full = self.trust, 0
            self._full_trust = trusted_fit(self.observations, self.spec, self.fit_options(), weights=weights,
                                           time_ns=time_ns, trust=self.trust)
            return self._full_trust
        cheap = trusted_fit(self.observations, self.spec, self.fit_options(), weights=weights, time_ns=time_ns,
                            trust=TrustOptions(anchors=self.trust.anchors, jackknife=False, draws=0))
        return carried(cheap, last)

    def drift(self) -> dict[str, bool]:
        """Per calibrated current: has it moved beyond the 95 % interval of the reference fit?

        The reference is the newest fit at least ``drift_lag_s`` (default one half-life) older
        than the latest; without one (or without a half-life and lag), nothing has drifted.
        """
        flags = dict.fromkeys(self.currents, False)
        lag = self.drift_lag_s if self.drift_lag_s is not None else self.half_life_s
        if self.latest is None or lag is None:
            return flags
        cutoff = self.latest.time_ns - lag * 1e9
        reference = next((r for t, r in reversed(self.history) if t <= cutoff), None)
        if reference is None:
            return flags
        for j, name in enumerate(self.latest.currents):
            if name not in reference.currents:
                continue
            i = reference.currents.index(name)
            lo, hi = reference.ci95_a[i]
            value = self.latest.calibrated_a[j]
            usable = bool(reference.identifiable[i] and self.latest.identifiable[j]) and np.isfinite([lo, hi]).all()
            flags[name] = bool(usable and not (lo <= value <= hi))
        return flags

    def reset(self) -> None:
        """Forget every run and fit (e.g. after a DIMM was replaced)."""
        self._full_trust = None
        self.observations.clear()
        self.history.clear()
        self.latest = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready state: settings, kept runs and the fit history (per-run details and the
        correlation matrix only in the latest fit)."""
        history = []
        for t, result in self.history:
            record = result.to_dict()
            if result is not self.latest:  # compact: no per-run details, no correlation matrix
                record["runs"] = []
                record["observability"].pop("correlation", None)
            history.append({"time_ns": int(t), "fit": record})
        return {
            "version": _STATE_VERSION,
            "settings": {
                "currents": list(self.currents), "half_life_s": self.half_life_s,
                "bounds": {k: list(v) for k, v in self.bounds.items()} if self.bounds else None,
                "intercept": self.intercept, "prior_weight": self.prior_weight, "names": list(self.names),
                "min_weight": self.min_weight, "max_history": self.max_history, "max_runs": self.max_runs,
                "drift_lag_s": self.drift_lag_s, "loo": self.loo, "rules": self.rules,
                "trust": None if self.trust is None else {"act_factor": self.trust.act_factor,
                                                          "draws": self.trust.draws,
                                                          "jackknife": self.trust.jackknife},
                "noise_floor": self.settings.noise_floor, "max_rel_ci": self.settings.max_rel_ci,
                "min_sensitivity": self.settings.min_sensitivity,
            },
            "observations": [o.to_dict() for o in self.observations],
            "history": history,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], spec: SpecLike) -> OnlineCalibrator:
        """Restore a calibrator from :meth:`to_dict` (the latest fit is recomputed from the runs).

        Raises:
            InputError: an unknown version or a malformed record.
        """
        if not isinstance(data, Mapping) or data.get("version") != _STATE_VERSION:
            raise InputError(f"calibrator state: version {getattr(data, 'get', lambda _k: None)('version')!r}; "
                             f"expected {_STATE_VERSION}")
        try:
            s = data["settings"]
            calib = cls(spec, currents=s["currents"], half_life_s=s["half_life_s"],
                        bounds={k: (float(v[0]), float(v[1])) for k, v in s["bounds"].items()} if s["bounds"] else None,
                        intercept=bool(s["intercept"]), prior_weight=float(s["prior_weight"]),
                        settings=FitSettings(noise_floor=float(s["noise_floor"]), max_rel_ci=float(s["max_rel_ci"]),
                                             min_sensitivity=float(s["min_sensitivity"])),
                        names=s["names"], min_weight=float(s["min_weight"]), max_history=int(s["max_history"]),
                        max_runs=int(s.get("max_runs", 2000)),
                        drift_lag_s=s["drift_lag_s"], loo=str(s["loo"]), rules=bool(s.get("rules", False)),
                        trust=None if not s.get("trust") else TrustOptions(
                            act_factor=float(s["trust"]["act_factor"]), draws=int(s["trust"]["draws"]),
                            jackknife=bool(s["trust"]["jackknife"])))
            calib.observations = [Observation.from_dict(o) for o in data["observations"]]
            calib.history = [(int(h["time_ns"]), FitResult.from_dict(h["fit"])) for h in data["history"]]
        except (KeyError, TypeError, ValueError, AttributeError) as error:
            raise InputError(f"calibrator state: malformed ({error!r})") from None
        if calib.observations:
            calib.latest = calib._fit(calib.weights(), max(o.time_ns for o in calib.observations))
            if calib.history:
                calib.history[-1] = (calib.history[-1][0], calib.latest)
        return calib
