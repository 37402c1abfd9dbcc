"""The node the model sees (issue 15): memory domains per socket and NUMA node, DIMMs per channel, the CPU
numbering, and where an announced CPU list puts a run's threads."""

from __future__ import annotations

import pytest

from hdeem_watch.dram.memspec import preset
from hdeem_watch.dram.node import HASWELL_EP, NodeTopology, idle_channel_stats, node_run_stats, topology_for
from hdeem_watch.errors import InputError

SPEC = preset("samsung-m393a1g43db0-cpb")
ICE_LAKE = NodeTopology(sockets=2, cores_per_socket=28, channels_per_socket=8, threads_per_core=2)


def test_the_default_is_the_taurus_blade_and_the_legacy_guess_for_8_dimms() -> None:
    """Nothing changes for the demo: 2 × 12 cores, 4 channels of one DIMM per socket, = topology_for(8)."""
    assert topology_for(8) == HASWELL_EP
    assert (HASWELL_EP.dimms, HASWELL_EP.domains, HASWELL_EP.dimms_per_domain) == (8, 2, 4)
    assert HASWELL_EP.threads_per_socket(18) == HASWELL_EP.domain_threads(18) == (12, 6)


def test_threads_without_cpus_fill_socket_0_first() -> None:
    """28 threads on a 2 × 28-core node all sit on socket 0 (the legacy 2 × 12 guess split them 16 + 12)."""
    assert ICE_LAKE.domain_threads(28) == (28, 0)
    assert ICE_LAKE.domain_threads(30) == (28, 2)
    assert topology_for(16).threads_per_socket(28) == (16, 12)  # what the model assumed before issue 15


def test_announced_cpus_place_the_threads() -> None:
    """A CPU list counts one thread per entry on its CPU's domain, SMT siblings (CPU 56+) included."""
    assert ICE_LAKE.domain_threads(28, cpus=range(28, 56)) == (0, 28)
    assert ICE_LAKE.domain_threads(4, cpus=[0, 56, 28, 84]) == (2, 2)
    with pytest.raises(InputError, match=r"cpu 112: not a CPU of this node; expected 0\.\.111"):
        ICE_LAKE.domain_of_cpu(112)


def test_snc_splits_a_socket_into_domains_of_its_channels() -> None:
    """SNC-2 on 2 × 20 cores, 6 channels: four domains of 3 channels; cores 0-9 in the first of socket 0."""
    snc = NodeTopology(sockets=2, cores_per_socket=20, channels_per_socket=6, numa_nodes_per_socket=2)
    assert (snc.domains, snc.channels_per_domain) == (4, 3)
    assert snc.domain_threads(12) == (10, 2, 0, 0)
    assert snc.domain_threads(3, cpus=[9, 10, 39]) == (1, 1, 0, 1)
    assert [snc.domain_of_channel(s, c) for s in (0, 1) for c in range(6)] == [0, 0, 0, 1, 1, 1, 2, 2, 2, 3, 3, 3]
    with pytest.raises(InputError, match="4 NUMA nodes per socket do not divide 6 channels"):
        NodeTopology(channels_per_socket=6, numa_nodes_per_socket=4)


def test_an_explicit_cpu_numbering_overrides_the_default() -> None:
    """Interleaved numbering (even CPUs on socket 0, odd on socket 1), as some BIOSes give."""
    interleaved = NodeTopology(cpu_domains=tuple(i % 2 for i in range(48)))
    assert interleaved.domain_threads(4, cpus=[0, 1, 2, 3]) == (2, 2)
    with pytest.raises(InputError, match="cpu 48: not a CPU of this node"):
        interleaved.domain_of_cpu(48)
    with pytest.raises(InputError, match=r"topology\.cpu_domains: domain 2"):
        NodeTopology(cpu_domains=(0, 2))


def test_a_run_on_socket_1_leaves_socket_0_idle() -> None:
    """The groups are per domain: the idle socket is an idle group of its DIMMs, the loaded one has traffic."""
    groups = node_run_stats(SPEC, "read", 1 << 22, 28, 2, ICE_LAKE, cpus=range(28, 56), max_requests=50_000)
    assert [n for _s, n in groups] == [8, 8]
    assert groups[0][0] == idle_channel_stats(SPEC)
    assert groups[1][0].total("rd") > 0


def test_two_dimms_per_channel_share_the_channels_traffic() -> None:
    """With 2 DPC each DIMM gets half the reads of a 1-DPC DIMM; the domain has twice the DIMMs."""
    one = NodeTopology(sockets=1, cores_per_socket=28, channels_per_socket=8)
    two = NodeTopology(sockets=1, cores_per_socket=28, channels_per_socket=8, dimms_per_channel=2)
    (s1, n1), = node_run_stats(SPEC, "read", 1 << 22, 8, 2, one, max_requests=50_000)
    (s2, n2), = node_run_stats(SPEC, "read", 1 << 22, 8, 2, two, max_requests=50_000)
    assert (n1, n2) == (8, 16)
    assert s2.total("rd") == pytest.approx(s1.total("rd") / 2, rel=0.02)
    assert n2 * s2.total("rd") == pytest.approx(n1 * s1.total("rd"), rel=0.02)


@pytest.mark.parametrize(("field", "value"), [("sockets", 0), ("dimms_per_channel", True), ("ranks_per_dimm", 0)])
def test_bad_counts_are_named(field: str, value: object) -> None:
    with pytest.raises(InputError, match=rf"topology\.{field}"):
        NodeTopology(**{field: value})  # type: ignore[arg-type]
