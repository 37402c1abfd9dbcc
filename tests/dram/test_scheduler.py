"""The FR-FCFS scheduler model: service order, write drains, tiny queues."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hdeem_watch.dram.scheduler import SchedulerConfig, service_order


def test_reads_to_an_open_row_are_served_first_within_the_window() -> None:
    """FR-FCFS: reads alternating between two rows of one bank are served row by row, each row's
    reads in arrival order, the row seen first first."""
    bank = np.zeros(8, dtype=np.int64)
    row = np.array([5, 9, 5, 9, 5, 9, 5, 9])
    order = service_order(bank, row, np.zeros(8, dtype=bool))
    assert order.tolist() == [0, 2, 4, 6, 1, 3, 5, 7]


def test_reads_to_different_banks_keep_their_rows_apart() -> None:
    """Grouping is by (bank, row): the same row number in two banks is two different rows."""
    bank = np.array([0, 1, 0, 1])
    row = np.array([3, 3, 4, 3])
    order = service_order(bank, row, np.zeros(4, dtype=bool))
    served = [(int(bank[i]), int(row[i])) for i in order]
    assert served.index((0, 4)) > served.index((0, 3))
    assert sorted(order.tolist()) == [0, 1, 2, 3]


@pytest.mark.parametrize("write_queue", [2, 3, 4])
def test_a_tiny_write_queue_drains_at_most_what_is_queued(write_queue: int) -> None:
    """With a low mark that rounds to no entry, a drain takes the writes queued when it starts,
    never more (it used to take more writes than existed and failed on a short stream)."""
    config = SchedulerConfig(write_queue=write_queue, low=0.2)
    assert 1 <= config.drain_batch <= config.drain_trigger
    is_write = np.zeros(12, dtype=bool)
    is_write[[1, 3, 8]] = True
    order = service_order(np.zeros(12, dtype=np.int64), np.arange(12), is_write, config)
    assert sorted(order.tolist()) == list(range(12))


def test_default_drain_matches_the_watermarks() -> None:
    """Ramulator's defaults (32 entries, 0.8 / 0.2): a drain starts at 26 queued writes and
    serves 21 (down to 5)."""
    config = SchedulerConfig()
    assert (config.drain_trigger, config.drain_batch) == (26, 21)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 400),
    write_queue=st.integers(2, 40),
    low=st.sampled_from([0.05, 0.2, 0.4]),
    hit_cap=st.sampled_from([None, 1, 4, 16]),
)
def test_the_service_order_is_a_permutation(seed: int, n: int, write_queue: int, low: float,
                                            hit_cap: int | None) -> None:
    """Every request is served exactly once, for any queue sizes, watermarks and hit cap."""
    rng = np.random.default_rng(seed)
    config = SchedulerConfig(write_queue=write_queue, low=low, high=max(0.8, low + 0.1), hit_cap=hit_cap)
    order = service_order(rng.integers(0, 8, n), rng.integers(0, 5, n), rng.random(n) < 0.4, config)
    assert np.array_equal(np.sort(order), np.arange(n))
