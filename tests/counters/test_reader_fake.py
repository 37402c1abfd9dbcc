"""The fake CounterReader behaves like perf_event_open(2) documents: counts accrue only while running."""

from __future__ import annotations

import errno

import pytest

from hdeem_watch.counters.arithmetic import scaled_delta
from hdeem_watch.counters.reader import CounterReader, FakeCounterReader


class Clock:
    def __init__(self) -> None:
        self.t = 1_000

    def __call__(self) -> int:
        return self.t


def per_ns(rate: float):
    return lambda pmu_type, config, cpu, elapsed_ns: int(rate * elapsed_ns)


def test_multiplexed_counts_scale_back_to_the_truth():
    """With a 25 % running share, the raw count is a quarter; scaling the window delta recovers it."""
    clock = Clock()
    reader: CounterReader = FakeCounterReader(per_ns(2.0), clock=clock, running_share=0.25)
    handle = reader.open(13, 0x304, 12)
    first = reader.read(handle)
    clock.t += 1_000_000
    second = reader.read(handle)
    assert second.value == 500_000 and second.time_running_ns == 250_000
    assert scaled_delta(first, second) == pytest.approx(2_000_000)
    reader.close(handle)


def test_value_wraps_at_the_counter_width():
    """A narrow counter wraps; the wrap-aware delta still recovers the count."""
    clock = Clock()
    reader = FakeCounterReader(per_ns(1.0), clock=clock, width_bits=16)
    handle = reader.open(13, 0x0, 0)
    clock.t += 60_000
    first = reader.read(handle)
    clock.t += 10_000
    second = reader.read(handle)
    assert second.value < first.value
    assert scaled_delta(first, second, width_bits=16) == 10_000


def test_errors_mimic_the_syscall():
    """Permission denied → EACCES; unknown PMU type → ENOENT; bad handle → EBADF; every open is closed."""
    with pytest.raises(OSError) as denied:
        FakeCounterReader(per_ns(1), denied=True).open(13, 0, 0)
    assert denied.value.errno == errno.EACCES
    reader = FakeCounterReader(per_ns(1), known_types=frozenset({13}))
    with pytest.raises(OSError) as missing:
        reader.open(99, 0, 0)
    assert missing.value.errno == errno.ENOENT
    handle = reader.open(13, 0, 0)
    assert reader.open_handles == 1
    reader.close(handle)
    with pytest.raises(OSError) as closed:
        reader.read(handle)
    assert closed.value.errno == errno.EBADF
    assert reader.open_handles == 0
