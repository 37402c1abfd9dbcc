"""The demo's runs carry their CPU list (issue 15): the CPUs the simulated threads run on, so the daemon
models each run on the sockets it ran on, as it does for ``hdeem-watch bench``."""

from __future__ import annotations

from typing import Any

import pytest

from hdeem_watch.demo.schedule import DemoRun, DemoSchedule, node_topology, sim_cpus
from hdeem_watch.dram.node import HASWELL_EP, NodeTopology
from hdeem_watch.sim.layout import SimLayout
from hdeem_watch.wire.client import ControlError

NODES = [HASWELL_EP, SimLayout.regular(2, 28, 8).topology, SimLayout.regular(1, 12, 6).topology]


@pytest.mark.parametrize("topology", NODES, ids=["taurus", "icelake", "one-socket"])
def test_the_announced_cpus_are_where_the_sim_puts_the_threads(topology: NodeTopology) -> None:
    """For every thread count up to one per core, the domains of the announced CPUs are the sim's
    placement (threads fill socket 0 first: NodeTopology.threads_per_socket, which the sim uses)."""
    for threads in range(1, topology.sockets * topology.cores_per_socket + 1):
        cpus = sim_cpus(threads, topology)
        assert cpus is not None and len(cpus) == threads
        assert topology.domain_threads(threads, cpus=cpus) == topology.threads_per_socket(threads)
    assert sim_cpus(topology.sockets * topology.cores_per_socket + 1, topology) is None


class FakeClient:
    """The control client's ``call``: answers run.start/run.stop and node.get as the daemon does."""

    def __init__(self, node: dict[str, Any] | None) -> None:
        self.node = node
        self.calls: list[tuple[str, Any]] = []

    def call(self, op: str, args: Any = None) -> Any:
        self.calls.append((op, args))
        if op == "node.get":
            if self.node is None:
                raise ControlError("unknown-op", "unknown op 'node.get'")
            return self.node
        return {"run_id": "r000001"} if op == "run.start" else {"state": "done"}


def test_the_schedule_announces_cpus_on_the_daemons_node() -> None:
    """node.get says 2 x 28 cores: a 12-thread run announces CPUs 0..11 (socket 0); an older daemon
    without node.get: the Taurus blade."""
    from hdeem_watch.bench.schedule import RunSpec

    client = FakeClient({"topology": {"sockets": 2, "cores_per_socket": 28, "channels_per_socket": 8}})
    schedule = DemoSchedule("ipc:///nonexistent", speed=1e6)
    schedule.topology = node_topology(client)  # type: ignore[arg-type]
    assert schedule.topology.cores_per_socket == 28
    assert schedule._one(client, 1, DemoRun(RunSpec("triad", 12, 1 << 20, 1), 1e-3))  # type: ignore[arg-type]
    start = next(args for op, args in client.calls if op == "run.start")
    assert start["metadata"]["cpus"] == list(range(12)) and start["metadata"]["simulated"] is True
    assert node_topology(FakeClient(None)) == HASWELL_EP  # type: ignore[arg-type]
