"""The daemon's per-sensor-group calibration: which sensor groups the node has, the guard rail on
a finished run, and the :class:`~hdeem_watch.calibrate.groups.GroupCalibrators` the run modeller
feeds (one fit per HDEEM DIMM pair or RAPL socket, beside the node fit).

Groups come from the source: the simulated node's layout (its sensors and the DIMMs behind each),
else the default Taurus mapping of the DRAM channels (``DDR_AB``/``DDR_CD`` on socket 0,
``DDR_EF``/``DDR_GH`` on socket 1, two DIMMs each; RAPL ``DRAM<n>`` the socket's DIMMs).

The guard rail (:meth:`GroupFits.unmeasured`): a run with fewer than ``min_samples`` samples of a
DRAM channel (default 100: 1 s at 100 Sa/s) or without a measured energy is recorded but not
fitted, and the reason goes into its record (``model_error``).

Pure apart from the source's description: no clock, no I/O; used on the model worker only.

Example:
    >>> groups = default_groups({"DDR_AB": 100.0, "DDR_CD": 100.0, "DDR_EF": 100.0, "DDR_GH": 100.0}, 2, 4)
    >>> [g.dimms_per_socket for g in groups]
    [(2, 0), (2, 0), (0, 2), (0, 2)]
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from hdeem_watch.calibrate.drift import DriftAlarm
from hdeem_watch.calibrate.group_rows import (
    DEFAULT_MIN_SAMPLES,
    SensorGroup,
    group_observation,
    measured_run,
    unmeasured_reason,
)
from hdeem_watch.channels import DRAM_SOCKET
from hdeem_watch.errors import InputError
from hdeem_watch.run_record import RunRecord
from hdeem_watch.sources.base import HasLayout

__all__ = ["DEFAULT_MIN_SAMPLES", "MAX_GROUP_RUNS", "GroupFits", "default_groups", "source_groups"]

#: Runs each group's calibrator keeps (oldest dropped first): five fits are saved at every stop.
MAX_GROUP_RUNS = 128
#: Fits each group's calibrator keeps in its own history.
MAX_GROUP_HISTORY = 16
#: Runs in a group's fit before its same-kind residual changes feed the drift detector (then 24 more
#: learn their scale) and its currents become the sibling comparison's reference: four times the six
#: unknowns (an earlier fit splits a run's energy between its length and its traffic too loosely for
#: two runs of one kind but other lengths to compare; on the demo's sim, changes in the first two
#: minutes reached 48 %).
DETECT_AFTER_RUNS = 24
_RAPL_PREFIX = "DRAM"


def default_groups(dram_rates_hz: Mapping[str, float], sockets: int, dimms_per_socket: int) -> list[SensorGroup]:
    """The groups of a node without a layout: HDEEM pairs on their Taurus socket (two DIMMs each),
    RAPL ``DRAM<n>`` with the DIMMs of socket ``n``; other channels are not grouped."""
    out = []
    for name in dram_rates_hz:
        counts = [0] * sockets
        if name in DRAM_SOCKET and DRAM_SOCKET[name] < sockets:
            counts[DRAM_SOCKET[name]] = 2
        elif name.startswith(_RAPL_PREFIX) and name[len(_RAPL_PREFIX):].isdigit() \
                and int(name[len(_RAPL_PREFIX):]) < sockets:
            counts[int(name[len(_RAPL_PREFIX):])] = dimms_per_socket
        if any(counts):
            out.append(SensorGroup(name, tuple(counts)))
    return out


def source_groups(source: object, dram_rates_hz: Mapping[str, float], sockets: int,
                  dimms_per_socket: int) -> tuple[SensorGroup, ...]:
    """The sensor groups of ``source``: from its layout when it simulates a node
    (:class:`~hdeem_watch.sources.base.HasLayout`), else :func:`default_groups`."""
    if isinstance(source, HasLayout):
        layout = source.layout
        return tuple(SensorGroup(s, tuple(sum(1 for d in layout.sensor_dimms(s) if layout.dimm_socket[d] == k)
                                          for k in range(layout.sockets)))
                     for s in layout.sensors)
    return tuple(default_groups(dram_rates_hz, sockets, dimms_per_socket))


class GroupFits:
    """The run modeller's per-group side: the guard rail, the group calibrators, their alarms.

    Args:
        spec: the memspec of one DIMM.
        groups: the sensor groups (none: only the guard rail runs).
        dram_rates_hz: sample rate of each DRAM channel (the guard rail checks every one; None:
            not known, no guard rail — the groups assume 100 Sa/s).
        min_samples: fewest samples per DRAM channel for a run to be fitted.
        calibrator: keyword arguments of each group's calibrator (currents, half_life_s, rules).
        state: a saved :meth:`state` to continue from (ignored when its groups differ).

    Attributes:
        calibrators: the group calibrators (None without groups).
        restore_error: why a saved state was not restored (None: restored or none given).
    """

    def __init__(self, spec: Any, groups: Sequence[SensorGroup], dram_rates_hz: Mapping[str, float] | None, *,
                 min_samples: int = DEFAULT_MIN_SAMPLES, calibrator: Mapping[str, Any] | None = None,
                 state: Mapping[str, Any] | None = None) -> None:
        from hdeem_watch.calibrate.groups import GroupCalibrators

        self.dram_rates_hz = None if dram_rates_hz is None else {str(k): float(v) for k, v in dram_rates_hz.items()}
        self.min_samples = int(min_samples)
        self.restore_error: str | None = None
        self.calibrators: GroupCalibrators | None = None
        self._pending: list[DriftAlarm] = []
        if not groups:
            return
        if state:
            try:
                restored = GroupCalibrators.from_dict(state, spec)
                if set(restored.groups) != {g.name for g in groups}:
                    raise InputError(f"groups {sorted(restored.groups)} differ from the node's "
                                     f"{sorted(g.name for g in groups)}")
                restored.min_samples = self.min_samples
                self.calibrators = restored
            except InputError as error:
                self.restore_error = f"group calibrators not restored: {error}"
        if self.calibrators is None:
            options = {**dict(calibrator or {}), "max_runs": MAX_GROUP_RUNS, "max_history": MAX_GROUP_HISTORY}
            self.calibrators = GroupCalibrators(spec, groups, min_samples=self.min_samples, calibrator=options,
                                                detect_after=DETECT_AFTER_RUNS)
        for calib in self.calibrators.calibrators.values():
            calib.rules = bool((calibrator or {}).get("rules", False))  # the setting, also over a restored state
            calib.max_runs = min(calib.max_runs, MAX_GROUP_RUNS)
            calib.max_history = min(calib.max_history, MAX_GROUP_HISTORY)
            del calib.observations[:-calib.max_runs]

    def unmeasured(self, record: RunRecord) -> str | None:
        """Why the run cannot be fitted (too few samples of a DRAM channel, a channel without
        energy), or None."""
        window = record.window_s
        window_s = window if window is not None and math.isfinite(window) else 0.0
        energies = record.energy_j or {}
        rates = self.dram_rates_hz
        if rates is None:
            return None
        name = f"{record.run_id}:{record.name or record.kernel}"
        reasons = []
        for channel, rate in rates.items():
            energy = energies.get(channel)
            samples = math.floor(window_s * rate + 1e-9)
            reason = unmeasured_reason(name, channel, energy, samples,
                                       window_s, self.min_samples)
            if reason is not None:
                reasons.append(reason)
        if not reasons:
            return None
        more = f" (and {len(reasons) - 1} more channels)" if len(reasons) > 1 else ""
        return f"not calibrated: {reasons[0]}{more}"

    def add(self, record: RunRecord, socket_stats: Sequence[tuple[Any, int]]) -> dict[str, Any]:
        """Fit the run into every group (and their node fit); keep the new alarms for :meth:`take_alarms`.

        Returns:
            The groups' calibration rows (group → ``Observation.to_dict()``), for the run's model
            (``calib export --group`` reads them back).
        """
        if self.calibrators is None:
            return {}
        run = measured_run(record, socket_stats, self.dram_rates_hz or {})
        rows = {}
        for name, group in self.calibrators.groups.items():
            if name in run.energy_j and math.isfinite(run.energy_j[name]):
                rows[name] = group_observation(self.calibrators.spec, run.socket_stats, group, run.window_s,
                                               float(run.energy_j[name]), name=run.name, time_ns=run.time_ns,
                                               traffic_s=run.traffic_s)
        update = self.calibrators.add_run(run)
        self._pending.extend(update.alarms)
        return {name: obs.to_dict() for name, obs in rows.items()}

    def take_alarms(self) -> list[DriftAlarm]:
        """The alarms raised since the last call (oldest first)."""
        alarms, self._pending = self._pending, []
        return alarms

    def has_run(self, run_name: str) -> bool:
        """Whether the node-of-groups fit already holds ``run_name`` (``"r3:triad"``)."""
        if self.calibrators is None:
            return False
        return any(any(o.name == run_name for o in c.observations) for c in self.calibrators.calibrators.values())

    def reset(self, group: str | None = None) -> None:
        """Forget the runs of ``group`` (None: every group and their node fit).

        Raises:
            InputError: an unknown group, or a group on a daemon without groups.
        """
        if self.calibrators is None:
            if group is not None:
                raise InputError(f"calib.reset: group {group!r}: this daemon keeps no per-group fits")
            return
        self.calibrators.reset(group)

    def body(self) -> dict[str, Any]:
        """``groups``, ``node`` (the fit of the groups' sum), ``alarms``, ``skipped``, ``min_samples``
        (docs/calibration.md); without groups only ``min_samples``."""
        if self.calibrators is None:
            return {"groups": {}, "alarms": [], "skipped": [], "min_samples": self.min_samples}
        return self.calibrators.body()

    def state(self) -> dict[str, Any] | None:
        """The groups' persistent state (bounded: :data:`MAX_GROUP_RUNS` runs per group)."""
        return None if self.calibrators is None else self.calibrators.to_dict()
