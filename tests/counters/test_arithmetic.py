"""Counter arithmetic: wrap, multiplexing scaling, window deltas, role sums."""

from __future__ import annotations

import math

from hdeem_watch.counters.arithmetic import (
    Reading,
    role_total,
    scale_multiplexed,
    scaled_delta,
    window_deltas,
    wrap_delta,
)
from hdeem_watch.counters.event_tables import IMC_COUNTER_BITS


def test_wrap_at_48_bits_and_64_bits():
    """A raw 48-bit IMC counter that wrapped once gives the true delta; perf values wrap at 2**64."""
    top = 1 << IMC_COUNTER_BITS
    assert wrap_delta(top - 100, 50, width_bits=IMC_COUNTER_BITS) == 150
    assert wrap_delta(10, 25, width_bits=IMC_COUNTER_BITS) == 15
    assert wrap_delta((1 << 64) - 1, 4) == 5
    assert wrap_delta(top - 100, 50) != 150  # the 64-bit view does not fold a 48-bit wrap


def test_multiplexing_scales_by_enabled_over_running():
    """value × enabled / running (perf_event_open(2)); unscaled when always running; NaN when never."""
    assert scale_multiplexed(100, 4_000, 1_000) == 400.0
    assert scale_multiplexed(100, 4_000, 4_000) == 100.0
    assert math.isnan(scale_multiplexed(0, 4_000, 0))


def test_window_delta_scales_the_window_not_the_history():
    """A window's estimate uses that window's enabled/running deltas only."""
    start = Reading(1_000, 10_000, 10_000)          # ran all the time before the window
    end = Reading(1_250, 20_000, 12_500)            # then a quarter of the window
    assert scaled_delta(start, end) == 1_000.0
    assert math.isnan(scaled_delta(end, start))     # times went backwards: re-opened event
    assert math.isnan(scaled_delta(start, Reading(1_000, 20_000, 10_000)))  # never ran in the window


def test_window_deltas_and_role_sums():
    """Per-event window deltas, summed per role; a missing or unknown event makes the role unknown."""
    before = {"A": Reading(0, 0, 0), "B": Reading(5, 0, 0)}
    after = {"A": Reading(10, 100, 100), "B": Reading(15, 100, 50), "C": Reading(3, 100, 100)}
    deltas = window_deltas(before, after)
    assert deltas["A"] == 10.0 and deltas["B"] == 20.0 and math.isnan(deltas["C"])
    assert role_total(deltas, ["A", "B"]) == 30.0
    assert math.isnan(role_total(deltas, ["A", "C"]))
    assert math.isnan(role_total(deltas, []))
