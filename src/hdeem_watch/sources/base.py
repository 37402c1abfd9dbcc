"""The source contract: what every power source (sim, HDEEM, RAPL, replay) gives the daemon.

A source is a small object behind the :class:`Source` protocol: ``open()``, then ``poll()`` at the
daemon's own pace (each call returns every sample that became due since the previous call, at the
channel's native rate, as a :class:`SourceBatch`), then ``close()``. Unknown values are NaN with a
status, never a silent 0. Times are integer nanoseconds: monotonic for intervals (the batch's
``t_mono_ns``), wall clock for labels (sample timestamps). Clocks are injectable.

The sources import this module and nothing above it; the factory that builds one by kind
(raising :class:`SourceUnavailable` with a reason a user can act on) is
:mod:`hdeem_watch.sources.registry`.

Example:
    >>> [info.name for info in hdeem_channel_infos()][:3]
    ['BLADE', 'CPU0', 'CPU1']
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol, runtime_checkable

import numpy as np

from hdeem_watch.channels import (  # noqa: F401 - re-exported: the sources' channel vocabulary
    CHANNELS,
    DRAM_CHANNELS,
    DRAM_SOCKET,
    RAPL_DRAM_COVERS,
    normalise_channel_name,
)

ChannelKind = Literal["blade", "cpu", "dram"]
Clock = Callable[[], int]

#: Status strings used by every source (plus ``"error: <reason>"``).
STATUS_OK = "ok"
STATUS_STALE = "stale"          # no new value for longer than expected (slow sensor call)
STATUS_OVERFLOW = "overflow"    # the sensor buffer overflowed: samples are missing
STATUS_GAP = "gap"              # the poller was late beyond the sensor buffer: samples are missing
STATUS_CLOSED = "closed"


class SourceUnavailable(RuntimeError):
    """A source cannot be used here; ``reason`` says why and what to do about it."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


@dataclass(frozen=True)
class ChannelInfo:
    """One measured channel.

    Attributes:
        name: channel name, e.g. ``"DDR_AB"`` (one of :data:`CHANNELS` for HDEEM and the sim;
            ``"DRAM0"``... for RAPL, see :data:`RAPL_DRAM_COVERS`).
        rate_hz: native sample rate (samples per second of the source's time).
        kind: ``"blade"``, ``"cpu"`` or ``"dram"``.
    """

    name: str
    rate_hz: float
    kind: ChannelKind


@dataclass(frozen=True)
class SourceBatch:
    """What one ``poll()`` returns.

    Attributes:
        t_mono_ns: monotonic time of the poll (the source's injected clock).
        t_wall_ns: wall-clock time of the poll.
        samples: per channel ``(t_wall_ns int64[n], power_w float64[n])`` — the new samples since
            the last poll at the channel's native rate (possibly none); NaN = unknown. A sample's
            timestamp is the end of the interval it averages (``1/rate_hz`` long).
        energy_j: cumulative energy per channel since the source opened (NaN if unknown).
        status: per channel ``"ok"``, ``"stale"``, ``"overflow"``, ``"gap"``, ``"error: ..."``.
    """

    t_mono_ns: int
    t_wall_ns: int
    samples: dict[str, tuple[np.ndarray, np.ndarray]]
    energy_j: dict[str, float]
    status: dict[str, str]
    gaps: dict[str, int] = field(default_factory=dict)
    """Samples known to be missing in this batch, per channel (0 or absent = none)."""

    def n_samples(self) -> int:
        """Total number of samples over all channels."""
        return sum(len(t) for t, _ in self.samples.values())


@dataclass(frozen=True)
class RunEvent:
    """A benchmark run starting or stopping, as announced to the daemon.

    Attributes:
        kind: ``"start"`` or ``"stop"``.
        run_id: the daemon's id of the run.
        kernel: kernel name (``"read"``, ``"triad"``, ...; ``"idle"``/``"sleep"`` = no traffic).
        threads: OpenMP threads (≥ 1).
        elements: array elements (doubles) per array.
        repeat: passes over the arrays.
        t_mono_ns: when it happened, on the daemon's monotonic clock (the same clock as the source's).
    """

    kind: Literal["start", "stop"]
    run_id: str
    kernel: str
    threads: int
    elements: int
    repeat: int
    t_mono_ns: int


@runtime_checkable
class Source(Protocol):
    """A power source. What only some sources can do is a capability protocol of its own
    (:class:`SpeedControlled`, :class:`HasTruth`, :class:`RunAware`)."""

    kind: str

    def channels(self) -> list[ChannelInfo]:
        """The channels this source measures."""
        ...

    def open(self) -> None:
        """Connect/start measuring. Raises :class:`SourceUnavailable` if it cannot."""
        ...

    def poll(self) -> SourceBatch:
        """Every sample due since the previous poll (no invented samples after a stall)."""
        ...

    def close(self) -> None:
        """Stop measuring and release resources (idempotent)."""
        ...

    def health(self) -> str:
        """``"ok"`` or a short description of what is wrong."""
        ...


@runtime_checkable
class SpeedControlled(Protocol):
    """A source whose time runs ``speed`` × the monotonic clock (the sim, a replay); fixed at open."""

    speed: float


@runtime_checkable
class HasTruth(Protocol):
    """A source that knows the truth behind its samples (the simulated node's hidden currents)."""

    def truth(self) -> Mapping[str, Any]:
        """The hidden truth as a JSON-ready mapping."""
        ...


class SensorLayout(Protocol):
    """Which DIMMs each DRAM sensor of a simulated node sums, on which socket, and the node's topology."""

    @property
    def topology(self) -> Any:
        """The simulated node's :class:`~hdeem_watch.dram.node.NodeTopology`."""
        ...

    @property
    def sensors(self) -> Sequence[str]:
        """The DRAM sensors."""
        ...

    @property
    def sockets(self) -> int:
        """Number of sockets."""
        ...

    @property
    def dimm_socket(self) -> Sequence[int]:
        """The socket of each DIMM."""
        ...

    def sensor_dimms(self, sensor: str) -> Sequence[int]:
        """The DIMMs ``sensor`` sums."""
        ...


@runtime_checkable
class HasLayout(Protocol):
    """A source that simulates a node: it knows its topology and which DIMMs each sensor sums."""

    @property
    def layout(self) -> SensorLayout:
        """The simulated node's layout."""
        ...


@runtime_checkable
class RunAware(Protocol):
    """A source that reacts to benchmark runs (the sim plays the announced run's traffic)."""

    def on_run(self, event: RunEvent) -> None:
        """A run started or stopped."""
        ...


@dataclass(frozen=True)
class QuietLimit:
    """How long a source may go unpolled without losing anything.

    Attributes:
        max_s: the longest stretch of the source's own time between two polls after which every
            sample and every joule is still there (a sensor buffer's depth, a counter's wrap time
            at its highest plausible power); ``math.inf`` = no limit.
        paced: each poll publishes one sample spanning the time since the previous read (a ΔE/Δt
            source: RAPL, HDEEM's energy method), so a longer stretch widens that sample instead of
            leaving samples out (the daemon then counts no missing samples between reads).
    """

    max_s: float
    paced: bool = False


@runtime_checkable
class QuietPolling(Protocol):
    """A source that says how rarely it may be polled while nobody watches (:class:`QuietLimit`).

    The daemon polls a source without it at its ``idle_poll_interval_s``.
    """

    @property
    def quiet_limit(self) -> QuietLimit:
        """This source's limit (it may depend on its settings, e.g. the read method)."""
        ...


def source_speed(source: object) -> float:
    """Source seconds per monotonic second: a :class:`SpeedControlled` source's positive finite
    ``speed``, else 1.

    >>> class Fast:
    ...     speed = 20.0
    >>> source_speed(Fast()), source_speed(object())
    (20.0, 1.0)
    """
    if isinstance(source, SpeedControlled):
        value = source.speed
        if isinstance(value, int | float) and not isinstance(value, bool) and 0 < value < float("inf"):
            return float(value)
    return 1.0


def hdeem_channel_infos() -> list[ChannelInfo]:
    """The HDEEM channel set: BLADE at 1000 Sa/s, CPU0/1 and the DIMM pairs at 100 Sa/s."""
    infos = [ChannelInfo("BLADE", 1000.0, "blade")]
    infos += [ChannelInfo(n, 100.0, "cpu") for n in ("CPU0", "CPU1")]
    infos += [ChannelInfo(n, 100.0, "dram") for n in DRAM_CHANNELS]
    return infos
