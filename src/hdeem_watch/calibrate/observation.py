"""One calibration row: the model's linear energy of a run beside the energy measured for it.

An :class:`Observation` is what the fit consumes: the energy model's columns (joules per ampere of
every current, in the order of :data:`hdeem_watch.dram.energy.CURRENT_NAMES`), the part of the
model energy that depends on no current (``constant_j``), and the measured energy. Rows are built
from runs by :func:`hdeem_watch.calibrate.rows.observation_from_run`; this module has no model code
so that the numerical core can be used (and tested) on plain matrices.

Example:
    >>> import numpy as np
    >>> obs = Observation("triad", np.array([1.0, 2.0]), constant_j=0.5, measured_j=3.0)
    >>> obs.predicted_j(np.array([1.0, 0.5]))
    2.5
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from hdeem_watch.errors import InputError

#: The currents the seed paper calibrates, and the default of :func:`~hdeem_watch.calibrate.fit`.
DEFAULT_CURRENTS: tuple[str, ...] = ("idd0", "idd2n", "idd3n", "idd4r", "idd4w")

def current_names(spec: object = None) -> tuple[str, ...]:
    """The current order of the energy model's columns for ``spec``'s standard.

    ``energy.CURRENT_NAMES`` (DDR4, also when no spec is given) or ``energy_ddr5.CURRENT_NAMES_DDR5``
    for a :class:`~hdeem_watch.dram.memspec_ddr5.MemSpecDDR5`.
    """
    from hdeem_watch.dram.linear import model_current_names

    return model_current_names(spec)


class SpecLike(Protocol):
    """What the fit needs of a memspec: its currents in amperes by lower-case name."""

    @property
    def currents(self) -> Mapping[str, float]:
        """Per-device currents in A."""
        ...


@dataclass(frozen=True)
class Observation:
    """A measured run as a linear equation in the currents.

    ``measured_j ≈ columns @ currents + constant_j (+ intercept)``.

    Attributes:
        name: the run's name (used in messages and reports).
        columns: J per A, one per current name (default order: ``energy.CURRENT_NAMES``).
        constant_j: the model energy that depends on no current.
        measured_j: the measured energy of the window, > 0.
        time_ns: wall-clock time of the run (its end), integer ns; used for forgetting.
        weight: relative weight of the row (1 = normal).
        window_s: the measured window in seconds (informational; NaN = unknown).
        commands: where the row's command counts come from: ``"counters"`` (counted in its
            window), ``"model"`` (the kernel model) or ``""`` (not said: a trace, a file).
        act_columns: the part of ``columns`` that the activations and their precharges carry (J per
            A; scales with the ACT count), for rows whose ACTs are modelled; None: not kept.
        act_factors: for a modelled row, its activation count under each other address-mapping
            family relative to the model's own (``dram.node.MAPPING_FAMILIES[1:]``); empty: none.
    """

    name: str
    columns: np.ndarray
    constant_j: float
    measured_j: float
    time_ns: int = 0
    weight: float = 1.0
    window_s: float = field(default=math.nan)
    commands: str = ""
    act_columns: np.ndarray | None = None
    act_factors: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        columns = np.asarray(self.columns, dtype=float)
        if columns.ndim != 1:
            raise InputError(f"run {self.name!r}: columns must be a 1-d array, got shape {columns.shape}")
        object.__setattr__(self, "columns", columns)
        if self.act_columns is not None:
            act = np.asarray(self.act_columns, dtype=float)
            if act.shape != columns.shape or not np.all(np.isfinite(act)):
                raise InputError(f"run {self.name!r}: act_columns must be finite and shaped like columns")
            object.__setattr__(self, "act_columns", act)
        factors = tuple(float(f) for f in self.act_factors)
        if not all(math.isfinite(f) and f >= 0 for f in factors):
            raise InputError(f"run {self.name!r}: act_factors must be finite and >= 0")
        object.__setattr__(self, "act_factors", factors)
        check_measured(self.name, self.measured_j)
        if not np.all(np.isfinite(columns)):
            raise InputError(f"run {self.name!r}: model columns contain NaN or infinity")
        if not math.isfinite(self.constant_j):
            raise InputError(f"run {self.name!r}: constant_j = {self.constant_j!r} is not finite")
        w = self.weight
        if isinstance(w, bool) or not isinstance(w, int | float) or not math.isfinite(w) or w < 0:
            raise InputError(f"run {self.name!r}: weight = {w!r}; expected a finite number >= 0")

    def predicted_j(self, currents_a: np.ndarray, intercept_j: float = 0.0) -> float:
        """Model energy for the given currents (same order as ``columns``)."""
        return float(self.columns @ np.asarray(currents_a, dtype=float) + self.constant_j + intercept_j)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (read back by :meth:`from_dict`)."""
        return {
            "name": self.name,
            "columns": [float(c) for c in self.columns],
            "constant_j": float(self.constant_j),
            "measured_j": float(self.measured_j),
            "time_ns": int(self.time_ns),
            "weight": float(self.weight),
            "window_s": None if math.isnan(self.window_s) else float(self.window_s),
            **({"commands": self.commands} if self.commands else {}),
            **({"act_columns": [float(c) for c in self.act_columns]} if self.act_columns is not None else {}),
            **({"act_factors": list(self.act_factors)} if self.act_factors else {}),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Observation:
        """Inverse of :meth:`to_dict`.

        Raises:
            InputError: a missing or malformed field.
        """
        try:
            window = data.get("window_s")
            return cls(
                name=str(data["name"]),
                columns=np.asarray(data["columns"], dtype=float),
                constant_j=float(data["constant_j"]),
                measured_j=float(data["measured_j"]),
                time_ns=int(data.get("time_ns", 0)),
                weight=float(data.get("weight", 1.0)),
                window_s=math.nan if window is None else float(window),
                commands=str(data.get("commands", "")),
                act_columns=None if data.get("act_columns") is None else np.asarray(data["act_columns"], dtype=float),
                act_factors=tuple(float(f) for f in data.get("act_factors") or ()),
            )
        except (KeyError, TypeError, ValueError) as error:
            raise InputError(f"observation {data.get('name', '?')!r}: malformed ({error})") from None


def check_measured(name: str, measured_j: Any) -> float:
    """Return ``measured_j`` as a float if it is a finite number > 0.

    Raises:
        InputError: ``run 'NAME': measured_j = ...`` otherwise.
    """
    if isinstance(measured_j, bool) or not isinstance(measured_j, int | float | np.floating | np.integer):
        raise InputError(f"run {name!r}: measured_j = {measured_j!r} is not a number; expected joules > 0")
    value = float(measured_j)
    if not math.isfinite(value) or value <= 0:
        raise InputError(f"run {name!r}: measured_j = {measured_j!r}; expected a finite energy > 0 J")
    return value


def stack(observations: Sequence[Observation], n_names: int) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                       np.ndarray]:
    """Columns (n×m), constants, measured energies and weights of ``observations`` as arrays.

    Raises:
        InputError: a row whose column count is not ``n_names``.
    """
    for obs in observations:
        if obs.columns.shape[0] != n_names:
            raise InputError(f"run {obs.name!r}: {obs.columns.shape[0]} model columns; expected {n_names}")
    columns = np.array([obs.columns for obs in observations], dtype=float).reshape(len(observations), n_names)
    constant = np.array([obs.constant_j for obs in observations], dtype=float)
    measured = np.array([obs.measured_j for obs in observations], dtype=float)
    weight = np.array([obs.weight for obs in observations], dtype=float)
    return columns, constant, measured, weight
