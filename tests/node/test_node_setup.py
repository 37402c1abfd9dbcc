"""What the daemon models (issue 15): the node description, its memspec with reason and confidence, the
run model's topology and the sensor map, from detection, the simulated node or the ``[node]`` table."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from hdeem_watch.node.description import describe_node
from hdeem_watch.node.overrides import parse_node_table
from hdeem_watch.node.setup import (
    DEFAULT_MEMSPEC,
    configured_only,
    counted_node,
    detect_live_node,
    dmidecode_text,
    node_setup,
)


def fixture_node(root: Path, name: str) -> Any:
    root = root / name
    return describe_node(root / "sys", (root / "dmidecode.txt").read_text(encoding="utf-8"), "fixture")


def test_a_detected_node_gives_its_memspec_topology_and_sensors(node_trees: Path) -> None:
    """Taurus: the part number names the preset (exact); 2 x 12 cores, 4 channels x 1 DIMM; HDEEM pairs."""
    setup = node_setup(fixture_node(node_trees, "haswell-ep-taurus"), None, memspec_setting=None)
    assert (setup.memspec, setup.choice.confidence) == ("samsung-m393a1g43db0-cpb", "exact")
    assert setup.topology is not None
    assert (setup.topology.sockets, setup.topology.cores_per_socket, setup.topology.channels_per_socket,
            setup.topology.dimms_per_channel, setup.topology.ranks_per_dimm) == (2, 12, 4, 1, 2)
    assert set(setup.sensors) >= {"DRAM0", "DRAM1", "DDR_AB", "DDR_GH"}
    lines = setup.log_lines()
    assert "samsung-m393a1g43db0-cpb [exact]" in lines[0] and "known module" in lines[0]
    assert "2 socket(s) x 12 cores" in lines[1] and "sysfs" in lines[1]
    body = setup.to_json()
    assert body["memspec"]["name"] == setup.memspec and body["topology"]["dimms"] == 8
    assert len(body["dimms"]) == 8


def test_two_dimms_per_channel_are_modelled_as_such(node_trees: Path) -> None:
    """The Ice Lake 2-DPC fixture: 2 x 8 channels of two DIMMs each, 32 DIMMs in the model."""
    setup = node_setup(fixture_node(node_trees, "icelake-sp-2dpc"), None, memspec_setting=None)
    assert setup.topology is not None and setup.topology.dimms == 32 and setup.topology.dimms_per_channel == 2


def test_the_memspec_precedence_node_table_then_setting_then_dimms_then_default(node_trees: Path) -> None:
    """[node] memspec beats the memspec setting, which beats the DIMMs; nothing at all is the default."""
    node = fixture_node(node_trees, "haswell-ep-taurus")
    table = parse_node_table({"memspec": "micron-4gb-x8-ddr4-2400-a"})
    assert node_setup(node, table, memspec_setting="ddr4-2133-x8-4gb").memspec == "micron-4gb-x8-ddr4-2400-a"
    chosen = node_setup(node, None, memspec_setting="ddr4-2133-x8-4gb")
    assert (chosen.memspec, chosen.choice.confidence) == ("ddr4-2133-x8-4gb", "configured")
    empty = node_setup(configured_only("nothing"), None, memspec_setting=None)
    assert (empty.memspec, empty.choice.confidence) == (DEFAULT_MEMSPEC, "default")
    sim = node_setup(counted_node(2, 12, 4, source="sim"), None, memspec_setting=None,
                     default_memspec=("ddr4-2133-x8-4gb", "the simulated DIMMs"))
    assert (sim.memspec, sim.choice.reason) == ("ddr4-2133-x8-4gb", "the simulated DIMMs")


def test_a_node_without_channels_keeps_the_default_topology_and_says_which_keys_to_set() -> None:
    """A VM sees no channels: no topology, and the note names the [node] keys."""
    setup = node_setup(configured_only("a VM"), None, memspec_setting=None)
    assert setup.topology is None
    assert "channels_per_socket" in setup.topology_note and "[node]" in setup.topology_note
    assert "node topology:" in setup.log_lines()[1]


def test_the_node_table_fills_what_detection_lacks_with_provenance_config() -> None:
    """[node] counts and [node.dimm] over a bare node: the model's topology and the DIMMs' preset follow."""
    table = parse_node_table({"sockets": 1, "cores_per_socket": 32, "channels_per_socket": 8,
                              "dimms_per_channel": 1, "dimm": {"part_number": "MTA18ASF2G72PDZ-2G3B1",
                                                               "size_gb": 16, "ranks": 2},
                              "sensors": {"DRAM0": ["S0-A1"]}})
    setup = node_setup(configured_only("a VM"), table, memspec_setting=None)
    assert setup.topology is not None and (setup.topology.sockets, setup.topology.dimms) == (1, 8)
    assert setup.description.channels_per_socket.source == "config [node]"
    assert (setup.memspec, setup.choice.confidence) == ("micron-8gb-x8-ddr4-2400-b", "exact")
    assert setup.sensors["DRAM0"] == ["S0-A1"]


def test_dmidecode_is_run_only_as_root_and_says_why_not() -> None:
    """Not installed, not root, failing: None and the reason; as root its print-out."""
    assert dmidecode_text(which=lambda _name: None)[0] is None
    text, why = dmidecode_text(which=lambda _name: "/usr/sbin/dmidecode", euid=1000)
    assert text is None and "not root" in why

    class Done:
        returncode, stdout, stderr = 0, "Handle 0x0041, DMI type 17, 40 bytes\nMemory Device\n", ""

    text, why = dmidecode_text(which=lambda _name: "/usr/sbin/dmidecode", euid=0, run=lambda *a, **k: Done())
    assert text is not None and "Memory Device" in text and why.startswith("dmidecode -t 17")


def test_live_detection_reads_the_injected_tree(node_trees: Path, tmp_path: Path) -> None:
    """detect_live_node on a fixture tree with a saved print-out (the daemon's path on hdeem/rapl nodes)."""
    root = node_trees / "skylake-sp"
    text = (root / "dmidecode.txt").read_text(encoding="utf-8")
    node = detect_live_node(root / "sys", cpuinfo=tmp_path / "none", dmidecode=(text, "saved"))
    assert node.sockets.value == 2 and node.channels_per_socket.value == 6 and len(node.dimms) == 12


@pytest.mark.parametrize("value", [0, "two", True])
def test_bad_counts_are_one_line_errors_naming_the_key(value: Any) -> None:
    """[node].sockets = 0 / "two" / true: the key and what was expected."""
    from hdeem_watch.errors import InputError

    with pytest.raises(InputError, match=r"\[node\]\.sockets = .*expected a positive integer"):
        parse_node_table({"sockets": value})
