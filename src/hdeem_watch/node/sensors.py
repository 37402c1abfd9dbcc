"""Which DIMMs each power sensor measures, from the node description.

- RAPL: the DRAM domain of package N (channel ``DRAM<N>`` of :mod:`hdeem_watch.sources.rapl`)
  measures socket N's DIMMs.
- HDEEM: one sensor per pair of consecutive channels of a socket, named by the node-wide channel
  letters: ``DDR_AB`` = socket 0 channels A and B, ``DDR_CD`` = channels C and D, ... (on the
  2 × 4-channel Haswell-EP blades HDEEM was built for: DDR_AB, DDR_CD, DDR_EF, DDR_GH).

An AMD node has neither (no DRAM energy sensor: :mod:`.dram_energy`), so its map is empty.

Overridable: the ``sensors`` key of the ``[node]`` table maps a sensor to DIMM locators.

Example:
    >>> from hdeem_watch.node.description import Dimm, NodeDescription
    >>> from hdeem_watch.node.facts import Fact
    >>> one = Fact(1, "test")
    >>> node = NodeDescription(Fact(1, "t"), one, Fact(4, "t"), one, one, Fact(2, "t"), one,
    ...                        dimms=(Dimm("A1", socket=0, channel=0), Dimm("B1", socket=0, channel=1)))
    >>> sensor_map(node)
    {'DRAM0': ['A1', 'B1'], 'DDR_AB': ['A1', 'B1']}
"""

from __future__ import annotations

from collections import defaultdict

from hdeem_watch.channels import dimm_pair_channel
from hdeem_watch.node.cpu_model import is_amd
from hdeem_watch.node.description import NodeDescription


def sensor_map(node: NodeDescription) -> dict[str, list[str]]:
    """Sensor name → locators of the DIMMs it measures (RAPL ``DRAM<N>`` first, then HDEEM pairs; none on
    AMD nodes, which have no DRAM sensor)."""
    if is_amd(node.cpu):
        return {}
    rapl: dict[str, list[str]] = defaultdict(list)
    pairs: dict[str, list[str]] = defaultdict(list)
    per_socket = node.channels_per_socket.value
    dimms = sorted(node.dimms, key=lambda d: (d.socket if d.socket is not None else 1 << 30,
                                              d.channel if d.channel is not None else 1 << 30, d.slot or 0))
    for dimm in dimms:
        if dimm.socket is None:
            continue
        rapl[f"DRAM{dimm.socket}"].append(dimm.locator)
        if dimm.channel is None or per_socket is None:
            continue
        pairs[dimm_pair_channel(dimm.socket, dimm.channel, per_socket)].append(dimm.locator)
    return {**dict(sorted(rapl.items())), **dict(sorted(pairs.items()))}
