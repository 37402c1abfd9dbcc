"""The nodes the demo can simulate (``hdeem-watch demo --node``), each with the thread counts of its rounds.

- ``haswell`` (the default): Taurus' Haswell-EP blade HDEEM was built for — 2 sockets × 12 cores,
  8 DDR4 DIMMs, HDEEM's four DIMM-pair sensors, a Haswell-EP IMC's counters.
- ``ddr5``: a Sapphire Rapids-like node — 2 sockets × 56 cores × 8 DDR5 DIMMs (16 sub-channels per
  socket, DRAMPower's DDR5 test memspec as a DDR5-4800 sub-channel), RAPL DRAM per socket
  (``DRAM0``/``DRAM1``), Sapphire Rapids' IMC counters with both pseudo-channels
  (:data:`hdeem_watch.sim.layout.DDR5_NODE`).

The thread counts of the rounds change the share of row misses per line and the split between the
sockets (threads fill socket 0 first): on the Haswell node 24 threads reach both sockets; on the
DDR5 node only more than 56 do, so two of its four rounds (112 and 72 threads) load socket 1 and
its sensor group has runs of its own to fit.

Example:
    >>> demo_node("ddr5").thread_rounds, demo_node("haswell").layout.sensors[0]
    (('112', '16', '72', '1'), 'DDR_AB')
"""

from __future__ import annotations

from dataclasses import dataclass

from hdeem_watch.errors import InputError
from hdeem_watch.sim.layout import DDR5_NODE, TAURUS, SimLayout


@dataclass(frozen=True)
class DemoNode:
    """One node the demo can simulate.

    Attributes:
        name: its ``--node`` name (the daemon's ``sim_node`` setting).
        title: what it is, in words (the demo's first line).
        layout: the simulated node.
        thread_rounds: the thread counts of the demo's rounds, cycled.
    """

    name: str
    title: str
    layout: SimLayout
    thread_rounds: tuple[str, ...]


#: The demo's nodes by ``--node`` name (the first is the default).
DEMO_NODES: dict[str, DemoNode] = {
    "haswell": DemoNode("haswell", "a Haswell-EP node (2 x 12 cores, 8 DDR4 DIMMs, HDEEM's DIMM pairs)",
                        TAURUS, ("24", "4", "12", "1")),
    "ddr5": DemoNode("ddr5", "a DDR5 node (2 x 56 cores, 2 x 8 DDR5 DIMMs, RAPL DRAM per socket)",
                     DDR5_NODE, ("112", "16", "84", "4")),
}


def demo_node(name: str) -> DemoNode:
    """The demo node called ``name``.

    Raises:
        InputError: an unknown name (one line naming the known ones).
    """
    node = DEMO_NODES.get(str(name))
    if node is None:
        raise InputError(f"--node {name}: unknown node; expected one of {', '.join(DEMO_NODES)}")
    return node
