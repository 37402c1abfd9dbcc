"""A window longer than the run's announced traffic: the traffic, then standby (calibrate/rows.py)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from hdeem_watch.calibrate.group_rows import SensorGroup, group_observation, run_kind
from hdeem_watch.calibrate.rows import observation_from_run
from hdeem_watch.dram.memspec import preset
from hdeem_watch.dram.node import HASWELL_EP, idle_channel_stats, node_run_stats
from hdeem_watch.run_record import RunRecord


def test_a_window_longer_than_the_traffic_is_the_traffic_then_standby() -> None:
    """With ``traffic_s`` = 1 s and a 1.6 s window the row is the run's statistics over 1 s plus an
    idle channel over 0.6 s — not the run's state mix stretched to 1.6 s; a window shorter than the
    traffic (or no traffic_s) is stretched as before."""
    spec = preset("samsung-m393a1g43db0-cpb")
    stats = node_run_stats(spec, "triad", 1 << 22, 24, 3, HASWELL_EP)[0][0]
    with_tail = observation_from_run(spec, stats, 1.6, 5.0, traffic_s=1.0)
    traffic = observation_from_run(spec, stats, 1.0, 5.0)
    idle = observation_from_run(spec, idle_channel_stats(spec), 0.6, 5.0)
    assert np.allclose(with_tail.columns, traffic.columns + idle.columns)
    assert with_tail.constant_j == pytest.approx(traffic.constant_j + idle.constant_j)
    stretched = observation_from_run(spec, stats, 1.6, 5.0)
    assert not np.allclose(with_tail.columns, stretched.columns)  # the active standby share differs
    assert np.allclose(observation_from_run(spec, stats, 0.8, 5.0, traffic_s=1.0).columns,
                       observation_from_run(spec, stats, 0.8, 5.0).columns)
    group = SensorGroup("DDR_AB", (2, 0))
    row = group_observation(spec, [(stats, 4), (stats, 4)], group, 1.6, 5.0, traffic_s=1.0)
    assert np.allclose(row.columns, 2 * with_tail.columns)


def test_run_kind_and_announced_traffic() -> None:
    """Runs of one kind share kernel, threads and announced CPUs; the traffic time is read from the
    run's metadata (``traffic_s`` before the demo's ``modelled_s``), never a bad value."""
    def run(**fields: Any) -> RunRecord:
        return RunRecord.from_dict({"run_id": "r1", "state": "modelling", **fields})

    assert run_kind(run(kernel="read", threads=4, elements=10)) == "read/4"
    assert run_kind(run(kernel="read", threads=4, elements=10, metadata={"cpus": [0, 1, 2, 3]})) == "read/4@0,1,2,3"
    assert run_kind(run(kernel="triad", threads=4, elements=0)) == "idle"
    assert run(metadata={"traffic_s": 2.0, "modelled_s": 1.0}).traffic_s == 2.0
    for bad in (None, -1.0, float("nan"), True, "1.5"):
        assert run(metadata={"modelled_s": bad}).traffic_s is None
