"""The sim's hidden command statistics survive the trip to an array and back, field by field."""

from __future__ import annotations

import dataclasses

import numpy as np

from hdeem_watch.dram.stats import CommandStats, RankStats
from hdeem_watch.sim.commands import FIELDS, array_stats, stats_array


def test_array_stats_inverts_stats_array_for_every_field() -> None:
    # every field a different value, so a field landing in its neighbour's place is seen
    ranks = tuple(RankStats(**{name: float(10 * r + i + 1) for i, name in enumerate(FIELDS)}) for r in range(2))
    stats = CommandStats(ranks=ranks)
    back = array_stats(stats_array(stats))
    assert back == stats
    assert all(type(getattr(rank, f.name)) is float for rank in back.ranks for f in dataclasses.fields(RankStats))


def test_array_stats_reads_a_float_array_of_ranks_by_fields() -> None:
    values = np.arange(2 * len(FIELDS), dtype=float).reshape(2, len(FIELDS))
    stats = array_stats(values)
    assert stats.total(FIELDS[0]) == values[0, 0] + values[1, 0]
    assert getattr(stats.ranks[1], FIELDS[-1]) == values[1, -1]
