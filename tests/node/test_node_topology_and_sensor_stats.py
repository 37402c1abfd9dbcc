"""The node description as the model sees it (issue 15): the topology from the detected fixtures, and a
run's statistics split per sensor (the rows of per-sensor calibration)."""

from __future__ import annotations

from pathlib import Path

import pytest

from hdeem_watch.calibrate.rows import node_observation
from hdeem_watch.dram.memspec import preset
from hdeem_watch.dram.node import idle_channel_stats, node_run_stats
from hdeem_watch.errors import InputError
from hdeem_watch.node.description import describe_node
from hdeem_watch.node.sensor_stats import dimm_channels, sensor_run_stats, split_by_sensor
from hdeem_watch.node.sensors import sensor_map
from hdeem_watch.node.topology import topology_from_node

SPEC = preset("samsung-m393a1g43db0-cpb")


def fixture(root: Path, name: str):  # type: ignore[no-untyped-def]
    return describe_node(root / name / "sys", (root / name / "dmidecode.txt").read_text(), "fixture")


@pytest.mark.parametrize(("name", "counts"), [
    ("haswell-ep-taurus", (2, 12, 1, 4, 1, 8)),
    ("icelake-sp-2dpc", (2, 28, 1, 8, 2, 32)),
    ("one-socket-skylake", (1, 12, 1, 6, 1, 6)),
    ("skylake-sp-snc2", (2, 20, 2, 6, 1, 12)),
    ("epyc-rome-8ch", (2, 16, 1, 8, 1, 16)),
])
def test_topology_of_each_fixture(node_trees: Path, name: str, counts: tuple[int, ...]) -> None:
    """(sockets, cores/socket, NUMA/socket, channels/socket, DIMMs/channel, DIMMs) as detected; every online
    CPU has a domain, and each socket's CPUs are in that socket's domains."""
    node = fixture(node_trees, name)
    topo = topology_from_node(node)
    assert (topo.sockets, topo.cores_per_socket, topo.numa_nodes_per_socket, topo.channels_per_socket,
            topo.dimms_per_channel, topo.dimms) == counts
    for socket, cpus in node.cpus_by_socket.items():
        assert {topo.socket_of_domain(topo.domain_of_cpu(c)) for c in cpus} == {socket}


def test_snc_domains_follow_the_kernels_node_cpulists(node_trees: Path) -> None:
    """On the SNC-2 fixture the core split matches sysfs node*/cpulist (node0 = CPUs 0-9,40-49, ...)."""
    topo = topology_from_node(fixture(node_trees, "skylake-sp-snc2"))
    root = node_trees / "skylake-sp-snc2" / "sys" / "devices" / "system" / "node"
    from hdeem_watch.node.cpu_topology import parse_cpu_list

    for numa in range(4):
        cpus = parse_cpu_list((root / f"node{numa}" / "cpulist").read_text())
        assert {topo.domain_of_cpu(c) for c in cpus} == {numa}


def test_unknown_counts_name_the_node_table_key(tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r"sockets, cores_per_socket, channels_per_socket unknown .*\[node\] table"):
        topology_from_node(describe_node(tmp_path, None, "none"))


def test_taurus_sensor_rows_of_a_socket_0_run(node_trees: Path) -> None:
    """12 threads on Taurus load socket 0: DDR_AB and DDR_CD see 2 loaded DIMMs each, DDR_EF/DDR_GH 2 idle
    ones; RAPL DRAM0 sees 4 loaded. The sensor rows add up to the node row."""
    node = fixture(node_trees, "haswell-ep-taurus")
    rows = sensor_run_stats(SPEC, node, "triad", 1 << 22, 12, 2, max_requests=50_000)
    idle = idle_channel_stats(SPEC)
    assert [(k, [n for _s, n in v]) for k, v in rows.items()] == [
        ("DRAM0", [4]), ("DRAM1", [4]), ("DDR_AB", [2]), ("DDR_CD", [2]), ("DDR_EF", [2]), ("DDR_GH", [2])]
    assert rows["DDR_AB"][0][0].total("wr") > 0 and rows["DDR_EF"][0][0] == idle
    node_row = node_observation(SPEC, node_run_stats(SPEC, "triad", 1 << 22, 12, 2, max_requests=50_000), 1.0, 10.0)
    pairs = [node_observation(SPEC, rows[s], 1.0, 2.5) for s in ("DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH")]
    assert sum(p.columns for p in pairs) == pytest.approx(node_row.columns)
    assert sum(p.constant_j for p in pairs) == pytest.approx(node_row.constant_j)


def test_under_snc_a_pair_can_straddle_two_domains(node_trees: Path) -> None:
    """SNC-2 with 3 channels per domain: DDR_CD = channel C (domain 0) + channel D (domain 1); a run on the
    first cluster's CPUs loads C but not D."""
    node = fixture(node_trees, "skylake-sp-snc2")
    topo = topology_from_node(node)
    groups = node_run_stats(SPEC, "read", 1 << 22, 10, 2, topo, cpus=range(10), max_requests=50_000)
    rows = split_by_sensor(topo, groups, sensor_map(node), dimm_channels(node))
    (c, nc), (d, nd) = rows["DDR_CD"]
    assert (nc, nd) == (1, 1) and c.total("rd") > 0 and d == idle_channel_stats(SPEC)
    assert [n for _s, n in rows["DRAM0"]] == [3, 3]


def test_bad_sensor_maps_are_named(node_trees: Path) -> None:
    node = fixture(node_trees, "haswell-ep-taurus")
    topo = topology_from_node(node)
    groups = node_run_stats(SPEC, "idle", 0, 1, 1, topo)
    with pytest.raises(InputError, match="DDR_XY: DIMM 'nope' has no known socket and channel"):
        split_by_sensor(topo, groups, {"DDR_XY": ["nope"]}, dimm_channels(node))
    with pytest.raises(InputError, match="DDR_XY: measures no DIMM"):
        split_by_sensor(topo, groups, {"DDR_XY": []}, dimm_channels(node))
    with pytest.raises(InputError, match="1 model groups; the node has 2 memory domains"):
        split_by_sensor(topo, groups[:1], sensor_map(node), dimm_channels(node))


def test_snc_domains_come_from_the_kernels_numa_cpu_lists() -> None:
    """Where the kernel's NUMA nodes do not follow the core order (here: even cores in cluster 0, odd in
    cluster 1), its node*/cpulist decides; a list that does not fit the counts falls back to the core split."""
    from hdeem_watch.node.description import NodeDescription
    from hdeem_watch.node.facts import Fact

    n = lambda v: Fact(v, "t")  # noqa: E731
    base = NodeDescription(n(1), n(1), n(4), n(1), n(2), n(6), n(1), cpus_by_socket={0: [0, 1, 2, 3]},
                           cpus_by_numa={0: [0, 2], 1: [1, 3]})
    assert topology_from_node(base).cpu_domains == (0, 1, 0, 1)
    odd = NodeDescription(n(1), n(1), n(4), n(1), n(2), n(6), n(1), cpus_by_socket={0: [0, 1, 2, 3]},
                          cpus_by_numa={0: [0, 1, 2, 3]})
    assert topology_from_node(odd).cpu_domains == (0, 0, 1, 1)


def test_the_node_report_says_what_the_model_makes_of_the_node(node_trees: Path, tmp_path: Path) -> None:
    """``hdeem-watch node --json``'s ``model``: memory domains and DIMMs of the SNC fixture; on a node without
    counts, the error naming the [node] keys."""
    from hdeem_watch.node.report import node_report

    view = node_report(fixture(node_trees, "skylake-sp-snc2"))["model"]
    assert view["error"] is None
    assert (view["memory_domains"], view["channels_per_domain"], view["dimms"]) == (4, 3, 12)
    assert view["cpu_numbering"] == "sysfs"
    empty = node_report(describe_node(tmp_path, None, "none"))
    assert "set sockets" in empty["model"]["error"] and empty["cpus_by_numa"] == {}
