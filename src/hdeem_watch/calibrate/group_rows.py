"""Sensor groups and their calibration rows: which DIMMs each sensor measures, per socket, and a
finished run as the groups see it.

A **sensor group** is a sensor and the DIMMs it measures, counted per socket
(:func:`sensor_groups` turns the node's sensor map — sensor → DIMM locators, see
:func:`hdeem_watch.node.sensors.sensor_map` — into groups). The model of a run gives the statistics
of ONE channel per socket (:func:`hdeem_watch.dram.node.node_run_stats`); a group's row is that
socket's row times the group's DIMMs on it, against the group's own measured energy
(:func:`group_observation`). :func:`unmeasured_reason` is the guard rail (too few samples, no
energy); :func:`measured_run` turns a daemon run record into the groups' input.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from hdeem_watch.calibrate.observation import Observation
from hdeem_watch.calibrate.rows import observation_from_run
from hdeem_watch.dram.memspec import MemSpec
from hdeem_watch.dram.stats import CommandStats
from hdeem_watch.errors import InputError
from hdeem_watch.run_record import RunRecord

#: Default fewest sensor samples per channel for a run to be fitted: 1 s at 100 Sa/s.
DEFAULT_MIN_SAMPLES = 100


@dataclass(frozen=True)
class SensorGroup:
    """A sensor and how many of each socket's DIMMs (channels) it measures.

    Example:
        >>> SensorGroup("DDR_EF", (0, 2)).dimms
        2
    """

    name: str
    dimms_per_socket: tuple[int, ...]

    @property
    def dimms(self) -> int:
        """DIMMs behind the sensor."""
        return sum(self.dimms_per_socket)


def sensor_groups(sensors: Mapping[str, Sequence[str]], dimm_socket: Mapping[str, int], sockets: int, *,
                  prefix: str | None = None) -> list[SensorGroup]:
    """The groups of a sensor map.

    Args:
        sensors: sensor → DIMM locators (:func:`hdeem_watch.node.sensors.sensor_map`).
        dimm_socket: DIMM locator → socket.
        sockets: sockets of the node.
        prefix: keep only sensors starting with it (``"DDR_"``: HDEEM pairs, ``"DRAM"``: RAPL).

    Raises:
        InputError: a DIMM without a socket, or a socket out of range.

    Example:
        >>> sensor_groups({"DDR_AB": ["A", "B"], "DDR_CD": ["C"]}, {"A": 0, "B": 0, "C": 1}, 2)
        [SensorGroup(name='DDR_AB', dimms_per_socket=(2, 0)), SensorGroup(name='DDR_CD', dimms_per_socket=(0, 1))]
    """
    out = []
    for name, dimms in sensors.items():
        if prefix is not None and not name.startswith(prefix):
            continue
        counts = [0] * int(sockets)
        for locator in dimms:
            socket = dimm_socket.get(locator)
            if socket is None or not 0 <= int(socket) < sockets:
                raise InputError(f"sensor map: {name}: DIMM {locator!r} has socket {socket!r}; expected 0..{sockets - 1}")
            counts[int(socket)] += 1
        if any(counts):
            out.append(SensorGroup(name, tuple(counts)))
    return out


def group_observation(spec: MemSpec, socket_stats: Sequence[tuple[CommandStats, int]], group: SensorGroup,
                      window_s: float, measured_j: float, *, name: str = "run", time_ns: int = 0,
                      traffic_s: float | None = None) -> Observation:
    """ONE calibration row of ``group``: each socket's one-channel row times the group's DIMMs on
    that socket, summed, against the group's measured energy. A model of one entry (the daemon's
    shortcut for idle runs: one channel's statistics for every DIMM) stands for every socket. A
    window longer than a known ``traffic_s`` is the run, then precharged standby
    (:func:`~hdeem_watch.calibrate.rows.observation_from_run`).

    Raises:
        InputError: the group names more sockets than the model has, or a bad window/energy.
    """
    if len(socket_stats) == 1 and len(group.dimms_per_socket) > 1:  # one model for the whole node (idle runs)
        socket_stats = [socket_stats[0]] * len(group.dimms_per_socket)
    if len(group.dimms_per_socket) > len(socket_stats):
        raise InputError(f"group {group.name}: {len(group.dimms_per_socket)} sockets; the model has {len(socket_stats)}")
    rows = [observation_from_run(spec, stats, window_s, measured_j, scale=float(k), name=name, time_ns=time_ns,
                                 traffic_s=traffic_s)
            for (stats, _n), k in zip(socket_stats, group.dimms_per_socket) if k > 0]
    if not rows:
        raise InputError(f"group {group.name}: measures no DIMM")
    return summed(rows, measured_j)


def summed(rows: Sequence[Observation], measured_j: float) -> Observation:
    """One row: the columns and constants of ``rows`` summed, against ``measured_j``."""
    first = rows[0]
    return Observation(name=first.name, columns=np.sum([r.columns for r in rows], axis=0),
                       constant_j=float(sum(r.constant_j for r in rows)), measured_j=float(measured_j),
                       time_ns=first.time_ns, weight=first.weight, window_s=first.window_s)


def unmeasured_reason(run: str, sensor: str, energy_j: float | None, samples: int, window_s: float,
                      min_samples: int = DEFAULT_MIN_SAMPLES) -> str | None:
    """Why a run cannot calibrate ``sensor`` (None: it can) — the guard rail, usable on its own.

    Example:
        >>> unmeasured_reason("r3:triad", "DDR_AB", 0.05, 1, 0.01)
        "run 'r3:triad': 1 samples of DDR_AB in 0.01 s; at least 100 are needed to measure a run (run it longer)"
    """
    if energy_j is None or not math.isfinite(energy_j) or energy_j <= 0:
        return f"run {run!r}: no measured energy of {sensor} ({energy_j!r})"
    if samples < min_samples:
        return (f"run {run!r}: {samples} samples of {sensor} in {window_s:.3g} s; at least "
                f"{min_samples} are needed to measure a run (run it longer)")
    return None


def measured_run(record: RunRecord, socket_stats: Sequence[tuple[CommandStats, int]],
                 rates_hz: Mapping[str, float]) -> MeasuredRun:
    """The :class:`MeasuredRun` of a daemon run record (:class:`~hdeem_watch.run_record.RunRecord`).

    Args:
        record: the finished run's record.
        socket_stats: the run's model (:func:`hdeem_watch.dram.node.node_run_stats`).
        rates_hz: each sensor's sample rate; the samples in the window are ``window_s × rate``.
    """
    window = record.window_s if record.window_s is not None and math.isfinite(record.window_s) else 0.0
    return MeasuredRun(name=f"{record.run_id}:{record.name or record.kernel}",
                       time_ns=record.t_stop_ns or 0, window_s=window, socket_stats=tuple(socket_stats),
                       energy_j=dict(record.energy_j or {}),
                       samples={c: math.floor(window * float(r) + 1e-9) for c, r in rates_hz.items()},
                       kind=run_kind(record), traffic_s=record.traffic_s)


def run_kind(record: RunRecord) -> str:
    """What makes two runs "the same kind" for the drift detector: kernel, threads and announced
    CPUs (any run without traffic is ``idle``).

    Example:
        >>> run = {"run_id": "r1", "state": "modelling", "threads": 24}
        >>> run_kind(RunRecord.from_dict({**run, "kernel": "triad", "elements": 1 << 24}))
        'triad/24'
        >>> run_kind(RunRecord.from_dict({**run, "kernel": "sleep", "elements": 0}))
        'idle'
    """
    if record.moves_no_traffic or not record.elements:
        return "idle"
    cpus = record.metadata.get("cpus")
    where = f"@{','.join(str(c) for c in cpus)}" if isinstance(cpus, list | tuple) and cpus else ""
    return f"{record.kernel}/{record.threads}{where}"


@dataclass(frozen=True)
class MeasuredRun:
    """A finished run as the groups see it.

    Attributes:
        name: unique name (e.g. ``"r12:triad"``).
        time_ns: end of the run (wall clock, ns).
        window_s: measured window (s).
        socket_stats: per socket, the model's statistics of one channel and the channel count
            (:func:`hdeem_watch.dram.node.node_run_stats`).
        energy_j: measured energy per sensor (J; NaN = unknown).
        samples: sensor samples inside the window per sensor (None: ``window_s × nominal rate``).
        kind: runs of one kind (:func:`run_kind`) are compared by the drift detector (None: the
            part of ``name`` after its first ``:``).
        traffic_s: how long the run's traffic lasted, when announced (``RunRecord.traffic_s``):
            the rest of the window is modelled as standby.
    """

    name: str
    time_ns: int
    window_s: float
    socket_stats: tuple[tuple[CommandStats, int], ...]
    energy_j: Mapping[str, float]
    samples: Mapping[str, int] | None = None
    kind: str | None = None
    traffic_s: float | None = None

    @property
    def kind_key(self) -> str:
        """:attr:`kind`, else the name without its run id (``"r7:triad-24t"`` → ``"triad-24t"``)."""
        return self.kind if self.kind is not None else self.name.split(":", 1)[-1]
