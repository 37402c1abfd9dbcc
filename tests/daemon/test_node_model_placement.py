"""The daemon's model of a run on the node it ran on (issue 15): the topology from the node, the CPUs the run
announced (metadata.cpus), the idle socket idle; older announcements (no cpus) and bad lists fall back to
threads filling socket 0 first, saying so."""

from __future__ import annotations

from typing import Any

import pytest

from hdeem_watch.calibrate import Observation
from hdeem_watch.calibrate.run_model import RunModeller, announced_cpus
from hdeem_watch.dram.node import NodeTopology, idle_channel_stats
from hdeem_watch.run_record import RunRecord

MEMSPEC = "samsung-m393a1g43db0-cpb"
ICE_LAKE = NodeTopology(sockets=2, cores_per_socket=28, channels_per_socket=8, threads_per_core=2)


def _record(threads: int, cpus: Any = None, kernel: str = "read") -> RunRecord:
    metadata = {} if cpus is None else {"cpus": cpus}
    return RunRecord.from_dict({"run_id": "r1", "state": "modelling", "kernel": kernel, "threads": threads, "elements": 1 << 22, "repeat": 2,
            "window_s": 1.0, "dram_energy_j": 40.0, "t_stop_ns": 1, "metadata": metadata})


def test_a_run_announced_on_socket_1_is_modelled_there() -> None:
    """28 threads on CPUs 28-55: socket 1's 8 DIMMs loaded, socket 0's idle; the node has 16 DIMMs."""
    m = RunModeller(MEMSPEC, topology=ICE_LAKE, max_requests=50_000)
    model, _fit, error = m.evaluate(_record(28, list(range(28, 56))))
    assert error is None and model is not None
    assert model["dimms"] == 16 and model["groups"] == [8, 8]
    assert model["placement"]["cpus"] == "announced cpus"
    assert [(d["socket"], d["threads"], d["dimms"]) for d in model["placement"]["domains"]] == [(0, 0, 8), (1, 28, 8)]
    groups = m.groups_for("read", 1 << 22, 28, 2, range(28, 56))
    assert groups[0][0] == idle_channel_stats(m.spec) and groups[1][0].total("rd") > 0
    assert model["counts"]["rd"] == pytest.approx(8 * groups[1][0].total("rd"))


def test_the_legacy_guess_models_the_ice_lake_run_on_both_sockets() -> None:
    """The same run with only a DIMM count (the model before issue 15) loads both sockets: a different row."""
    new = RunModeller(MEMSPEC, topology=ICE_LAKE, max_requests=50_000).evaluate(_record(28))[0]
    old = RunModeller(MEMSPEC, dimms=16, max_requests=50_000).evaluate(_record(28))[0]
    assert new is not None and old is not None
    assert [d["threads"] for d in new["placement"]["domains"]] == [28, 0]
    assert [d["threads"] for d in old["placement"]["domains"]] == [16, 12]
    assert Observation.from_dict(new["observation"]).columns.tolist() != \
        Observation.from_dict(old["observation"]).columns.tolist()


@pytest.mark.parametrize(("cpus", "why"), [
    (None, "no cpus announced"),
    ([0, 1], "not one CPU per thread"),
    (["0"] * 4, "not one CPU per thread"),
    ([0, 1, 2, 500], "cpu 500: not a CPU of this node"),
])
def test_without_a_usable_cpu_list_threads_fill_socket_0(cpus: Any, why: str) -> None:
    """An older bench (no list), a list of the wrong length or type, or a CPU the node lacks: the default
    placement, and the model says why."""
    model, _fit, error = RunModeller(MEMSPEC, topology=ICE_LAKE, max_requests=50_000).evaluate(_record(4, cpus))
    assert error is None and model is not None
    assert model["placement"]["cpus"].startswith("default: ") and why in model["placement"]["cpus"]
    assert [d["threads"] for d in model["placement"]["domains"]] == [4, 0]


def test_announced_cpus_validation() -> None:
    assert announced_cpus(_record(2, [3, 3])) == ((3, 3), "announced cpus")
    assert announced_cpus(_record(1, [True]))[0] is None
    assert announced_cpus(_record(1, "x"))[0] is None


def test_the_nodes_ranks_reshape_the_memspec() -> None:
    """A topology that knows its DIMMs are single-rank models one rank per DIMM; unknown ranks keep the memspec's."""
    one_rank = RunModeller(MEMSPEC, topology=NodeTopology(ranks_per_dimm=1))
    assert one_rank.spec.nbr_of_ranks == 1 and len(one_rank.groups_for("idle", 0, 1, 1)[0][0].ranks) == 1
    assert RunModeller(MEMSPEC, topology=NodeTopology()).spec.nbr_of_ranks == 2
    model, _fit, error = one_rank.evaluate(_record(1, kernel="idle"))
    assert error is None and model is not None and model["placement"]["topology"]["ranks_per_dimm"] == 1
