"""The counter source of the daemon's ``counters`` setting: ``"perf" | "sim" | "replay" | "none"``.

- ``sim``: the simulated node's own IMC counters, which the power source offers itself
  (:class:`OffersSimCounters`; :class:`~hdeem_watch.sim.counters.SimCounters`).
- ``perf``: the host plan's events through ``perf_event_open``
  (:class:`~hdeem_watch.counters.perf_counters.PerfCounters`).
- ``replay``: the counters recorded beside a recording, played with it (the caller opens them:
  the recording format is the daemon's).
- ``none``: no counters (runs are modelled from their kernel only).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable

from hdeem_watch.counters.source import COUNTER_KINDS, CounterSource
from hdeem_watch.errors import InputError


@runtime_checkable
class OffersSimCounters(Protocol):
    """A power source with a simulated memory controller (the sim)."""

    def sim_counters(self) -> CounterSource:
        """The counters of its memory controller."""
        ...


@runtime_checkable
class HasKind(Protocol):
    """A power source that says its kind (``"sim"``, ``"hdeem"``, ...)."""

    kind: str


@runtime_checkable
class HasPowerChannels(Protocol):
    """A power source that names its channels (each with a ``name``)."""

    def channels(self) -> list:
        """Its measured channels."""
        ...


def make_counter_source(kind: str, source: object, *, sample_time: Callable[[int], int], clock: Callable[[], int],
                        ranks: int = 2, sysfs_root: str | None = None,
                        replay: Callable[[], CounterSource] | None = None) -> CounterSource | None:
    """The configured counter source (None for ``"none"``).

    Args:
        kind: the ``counters`` setting.
        source: the power source.
        sample_time: monotonic ns → the power samples' time axis (perf).
        clock: monotonic clock in ns (perf).
        ranks: ranks per channel (perf).
        sysfs_root: where to discover the PMUs (perf; default the real sysfs).
        replay: opens the recorded counters (``replay``; None: no recording given).

    Raises:
        InputError: one line: the kind cannot work with this power source or host, and why.
    """
    if kind == "none":
        return None
    if kind == "sim":
        if not isinstance(source, OffersSimCounters):
            named = source.kind if isinstance(source, HasKind) else "?"
            raise InputError(f"counters = 'sim' needs source = 'sim' (the {named} source "
                             "has no simulated memory controller); use counters = 'perf' on a real node")
        return source.sim_counters()
    if kind == "perf":
        from hdeem_watch.counters.host_plan import plan_host
        from hdeem_watch.counters.perf_counters import PerfCounters, imc_sensors
        from hdeem_watch.counters.perf_reader import PerfCounterReader
        from hdeem_watch.counters.pmu_discovery import DEFAULT_SYSFS_ROOT

        plan = plan_host(sysfs_root or DEFAULT_SYSFS_ROOT, ranks=ranks)
        if not plan.usable:
            raise InputError("counters perf: " + "; ".join(plan.reasons))
        names = {info.name for info in source.channels()} if isinstance(source, HasPowerChannels) else set()
        return PerfCounters(plan, PerfCounterReader(), sample_time=sample_time, clock=clock, ranks=ranks,
                            sensors=imc_sensors(plan.channels, names))
    if kind == "replay":
        if replay is None:
            raise InputError("counters = 'replay' needs source = 'replay' and its recording (replay_file)")
        return replay()
    raise InputError(f"counters = {kind!r}; expected one of {', '.join(COUNTER_KINDS)}")
