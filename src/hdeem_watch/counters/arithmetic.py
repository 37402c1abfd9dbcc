"""Counter arithmetic as pure functions: wrap, multiplexing scaling, window deltas, role sums.

A ``perf_event`` read gives ``(value, time_enabled, time_running)``. When a PMU has more events than
hardware counters (an IMC channel box has 4 generic counters; a full DRAM model needs 12 or more
events), the kernel multiplexes: each event counts only while it is scheduled (``time_running``)
and ``value × time_enabled / time_running`` estimates the full count (Linux
``perf_event_open(2)``, ``PERF_FORMAT_TOTAL_TIME_ENABLED/RUNNING``). Over a window the estimate is
taken on the *deltas* of the three numbers, so a window's scaling does not depend on earlier
windows. A window in which the event never ran has no estimate: NaN, never 0.

Counter width: the kernel accumulates uncore counts in 64 bits (it folds the 48-bit hardware
counter into the event's count on every read and on a timer), so values read through perf wrap at
2**64; raw hardware values (MMIO/PCI reads, recordings of them) wrap at 2**48
(:data:`~hdeem_watch.counters.event_tables.IMC_COUNTER_BITS`). :func:`wrap_delta` takes the width.

Example:
    >>> wrap_delta(2**48 - 10, 5, width_bits=48)
    15
    >>> scaled_delta(Reading(100, 1_000, 1_000), Reading(300, 3_000, 2_000))
    400.0
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

#: Width of values read through ``perf_event`` (the kernel's 64-bit accumulated count).
PERF_COUNT_BITS = 64


@dataclass(frozen=True)
class Reading:
    """One ``perf_event`` read with ``PERF_FORMAT_TOTAL_TIME_ENABLED | _RUNNING``.

    Attributes:
        value: the raw count.
        time_enabled_ns: nanoseconds the event was enabled.
        time_running_ns: nanoseconds it was actually on a counter (``<= time_enabled_ns``).
    """

    value: int
    time_enabled_ns: int
    time_running_ns: int


def wrap_delta(previous: int, current: int, width_bits: int = PERF_COUNT_BITS) -> int:
    """``current − previous`` of a counter that wraps at ``2**width_bits`` (at most one wrap)."""
    return (current - previous) % (1 << width_bits)


def scale_multiplexed(value: float, time_enabled_ns: float, time_running_ns: float) -> float:
    """``value × enabled / running``; the value itself when never multiplexed; NaN when it never ran."""
    if time_running_ns <= 0:
        return math.nan
    if time_running_ns >= time_enabled_ns:
        return float(value)
    return float(value) * time_enabled_ns / time_running_ns


def scaled_delta(previous: Reading, current: Reading, width_bits: int = PERF_COUNT_BITS) -> float:
    """The estimated count between two reads of one event (wrap, then multiplexing scaling).

    Returns:
        The count over the window, NaN when the event was not running at all in it, or when the
        times went backwards (a re-opened event: the window cannot be trusted).
    """
    enabled = current.time_enabled_ns - previous.time_enabled_ns
    running = current.time_running_ns - previous.time_running_ns
    if enabled < 0 or running < 0:
        return math.nan
    return scale_multiplexed(wrap_delta(previous.value, current.value, width_bits), enabled, running)


def window_deltas(previous: Mapping[str, Reading], current: Mapping[str, Reading],
                  width_bits: int = PERF_COUNT_BITS) -> dict[str, float]:
    """:func:`scaled_delta` of every event read at both ends of a window (NaN for one read only)."""
    return {name: (scaled_delta(previous[name], reading, width_bits) if name in previous else math.nan)
            for name, reading in current.items()}


def role_total(event_deltas: Mapping[str, float], event_names: Iterable[str]) -> float:
    """Sum of the deltas of a role's events; NaN when the role has no events or one is unknown."""
    names = list(event_names)
    if not names:
        return math.nan
    return float(sum(event_deltas.get(name, math.nan) for name in names))
