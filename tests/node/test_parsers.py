"""The pure parsers behind ``hdeem-watch node``: dmidecode, slot names, EDAC, CPU lists, [node]."""

from __future__ import annotations

from pathlib import Path

import pytest

from hdeem_watch.dram.memspec import preset
from hdeem_watch.errors import InputError
from hdeem_watch.node.cpu_topology import parse_cpu_list, read_cpu_topology
from hdeem_watch.node.description import Dimm, describe_node
from hdeem_watch.node.dmidecode import parse_dmidecode
from hdeem_watch.node.edac import read_edac
from hdeem_watch.node.locators import parse_location
from hdeem_watch.node.memspec_choice import choose_memspec, devices_per_rank, for_dimm, width_from_part_number
from hdeem_watch.node.overrides import parse_node_table


def test_dmidecode_versions_and_empty_slots(node_trees: Path) -> None:
    """2.12 spells sizes in MB and speeds in MHz; 3.x in GB and MT/s; an empty slot has no size."""
    old = parse_dmidecode((node_trees / "haswell-ep-taurus" / "dmidecode.txt").read_text())
    new = parse_dmidecode((node_trees / "skylake-sp" / "dmidecode.txt").read_text())
    assert (old[0].size_bytes, old[0].speed_mts, old[0].configured_mts) == (8 << 30, 2133, 2133)
    assert (new[0].size_bytes, new[0].speed_mts, new[0].configured_mts) == (16 << 30, 2666, 2666)
    assert new[0].part_number == "M393A2K43BB1-CTD"          # padding removed
    empty = new[1]
    assert not empty.installed and empty.part_number is None and empty.ranks is None and empty.manufacturer is None
    assert len(new) == 24 and sum(d.installed for d in new) == 12


def test_dmidecode_skips_other_types_and_junk() -> None:
    """Other DMI types and text without records give no device."""
    text = "Handle 0x0001, DMI type 16, 23 bytes\nPhysical Memory Array\n\tLocation: System Board\n"
    assert parse_dmidecode(text) == []
    assert parse_dmidecode("/dev/mem: Permission denied\n") == []


@pytest.mark.parametrize(("locator", "bank", "expect"), [
    ("CPU_SrcID#1_MC#3_Chan#1_DIMM#1", None, (1, 3, 1, None, 1)),
    ("CPU_SrcID#0_Ha#1_Chan#0_DIMM#0", None, (0, 1, 0, None, 0)),
    ("P2-DIMMD2", "P1_Node1_Channel3_Dimm1", (1, None, 3, "D", 1)),
    ("DIMM 1", "P1 CHANNEL G", (1, None, None, "G", 0)),
    ("CPU2_DIMM_C1", "NODE 2", (1, None, None, "C", 0)),
    ("PROC 1 DIMM 3", None, (None, None, None, None, None)),
    ("DIMM_P1_B2", "BANK 1", (1, None, None, "B", 1)),
    ("A7", None, (None, None, None, "A", 6)),
])
def test_slot_names(locator: str, bank: str | None, expect: tuple[object, ...]) -> None:
    """Board and kernel slot names give socket (0-based), controller, channel or letter, slot."""
    g = parse_location(locator, bank)
    assert (g.socket, g.controller, g.channel, g.letter, g.slot) == expect


def test_edac_csrow_kernels(tmp_path: Path) -> None:
    """Old kernels (csrow only) still give size and type, one entry per rank; empty csrows are skipped."""
    mc = tmp_path / "devices" / "system" / "edac" / "mc" / "mc0"
    for i, size in enumerate((4096, 4096, 0)):
        row = mc / f"csrow{i}"
        row.mkdir(parents=True)
        (row / "size_mb").write_text(f"{size}\n")
        (row / "mem_type").write_text("Registered-DDR3\n")
        (row / "dev_type").write_text("x4\n")
        (row / "ch0_dimm_label").write_text(f"CPU_SrcID#0_Channel#0_DIMM#{i}\n")
    dimms, note = read_edac(tmp_path)
    assert len(dimms) == 2 and "csrow" in note and dimms[0].dev_type == "x4" and dimms[0].size_mb == 4096


def test_cpu_lists_and_missing_sysfs(tmp_path: Path) -> None:
    """Kernel CPU lists expand; a tree without topology says why everything is unknown."""
    assert parse_cpu_list("0-2,5,7-8\n") == [0, 1, 2, 5, 7, 8] and parse_cpu_list("") == []
    topo = read_cpu_topology(tmp_path)
    assert topo.sockets.value is None and "not Linux" in topo.sockets.source


def test_snc_numa_per_socket(node_trees: Path) -> None:
    """SNC2: two NUMA nodes per socket, mapped to their socket."""
    topo = read_cpu_topology(node_trees / "skylake-sp-snc2" / "sys")
    assert topo.numa_nodes_per_socket.value == 2 and topo.numa_by_socket == {0: [0, 1], 1: [2, 3]}


def test_vm_note(tmp_path: Path) -> None:
    """A hypervisor (CPU flag or DMI vendor) is named as the reason nothing is seen."""
    node = describe_node(tmp_path, None, "not root", cpuinfo_text="flags\t\t: fpu vme hypervisor lahf_lm\n")
    assert any(n.startswith("a virtual machine (the CPU flag 'hypervisor')") for n in node.notes)
    dmi = tmp_path / "class" / "dmi" / "id"
    dmi.mkdir(parents=True)
    (dmi / "sys_vendor").write_text("QEMU\n")
    assert any("sys_vendor 'QEMU'" in n for n in describe_node(tmp_path, None, "x").notes)


@pytest.mark.parametrize(("part", "ranks", "width"), [
    ("M393A1G43DB0-CPB", 2, 8), ("M393A4K40DB2-CVF", 2, 4), ("HMA82GR7AFR8N-VK", 2, 8), ("HMA84GR7AFR4N-UH", 2, 4),
    ("MTA18ASF2G72PDZ-2G3B1", 2, 8), ("MTA36ASF4G72PZ-3G2R1", 2, 4), ("MTA18ASF2G72PZ-2G3B1", 1, 4),
    ("KVR24R17D8/16", 2, None),
])
def test_width_from_part_number(part: str, ranks: int, width: int | None) -> None:
    """The organisation code of Samsung, SK hynix and Micron part numbers gives the device width."""
    assert width_from_part_number(part, ranks) == width


def test_choice_and_reshape() -> None:
    """Density from size, ranks and width picks the preset; for_dimm reshapes it to the DIMM."""
    dimm = Dimm("X", size_bytes=16 << 30, type="DDR4", speed_mts=2400, ranks=2, total_width=72,
                part_number="HMA82GR7AFR8N-UH")
    choice = choose_memspec([dimm])
    assert (choice.name, choice.confidence, choice.die_gbit, choice.device_width) == \
        ("micron-8gb-x8-ddr4-2400-b", "high", 8, 8)
    ddr5 = Dimm("Y", type="DDR5", speed_mts=4800)
    assert choose_memspec([ddr5]).name is None and "DDR5" in choose_memspec([ddr5]).reason
    spec = for_dimm(preset("micron-8gb-x8-ddr4-2400-b"), 1, devices_per_rank(dimm, 4))
    assert (spec.nbr_of_ranks, spec.nbr_of_devices) == (1, 18)
    assert choose_memspec([]).confidence == "none"


@pytest.mark.parametrize(("table", "expect"), [
    ({"sockets": 0}, "[node].sockets = 0: expected a positive integer"),
    ({"cores_per_socket": "12"}, "cores_per_socket = '12'"),
    ({"dimm": {"rank": 2}}, "[node].dimm: unknown key 'rank'"),
    ({"dimm": {"part_number": 5}}, "part_number = 5: expected a string"),
    ({"sensors": {"DDR_AB": "A1"}}, "sensors.DDR_AB = 'A1': expected a list"),
    ({"memspec": ""}, "memspec = ''"),
])
def test_node_table_errors(table: dict[str, object], expect: str) -> None:
    """Each wrong [node] value is one line naming the key."""
    with pytest.raises(InputError) as info:
        parse_node_table(table)
    assert expect in str(info.value) and "\n" not in str(info.value)


def test_choice_gives_the_dimm_organisation() -> None:
    """The choice carries ranks and devices per rank, so the preset can be reshaped to the DIMM."""
    dimm = Dimm("X", size_bytes=32 << 30, type="DDR4", speed_mts=2933, ranks=2, total_width=72,
                part_number="M393A4K40DB2-CVF")
    choice = choose_memspec([dimm])
    assert (choice.ranks, choice.devices_per_rank, choice.device_width, choice.die_gbit) == (2, 18, 4, 8)
    spec = for_dimm(preset(choice.name), choice.ranks, choice.devices_per_rank)  # type: ignore[arg-type]
    assert (spec.nbr_of_ranks, spec.nbr_of_devices) == (2, 18)


def test_letter_only_slot_names_are_flagged(tmp_path: Path) -> None:
    """Bare slot names ('A1') are placed by a guess, and the notes say so."""
    text = "".join(
        f"Handle 0x00{i:02X}, DMI type 17, 84 bytes\nMemory Device\n\tSize: 16 GB\n\tLocator: {name}\n"
        f"\tBank Locator: Not Specified\n\tType: DDR4\n\tRank: 2\n\n"
        for i, name in enumerate(("A1", "B1", "C1", "D1")))
    node = describe_node(tmp_path, text, "dmi.txt")
    assert any("board-specific" in n for n in node.notes)
    assert all(d.sources["socket"].startswith("unknown") for d in node.dimms)


@pytest.mark.parametrize(("part", "size_gib", "ranks", "speed", "expect"), [
    ("MTA36ASF4G72PZ-2G3B1", 32, 2, 2400, ("micron-8gb-x4-ddr4-2400-b", "exact")),
    ("MTA9ASF1G72PZ-2G3B1", 8, 1, 2400, ("micron-8gb-x8-ddr4-2400-b", "exact")),
    ("HMA84GR7AFR4N-UH", 32, 2, 2400, ("micron-8gb-x4-ddr4-2400-b", "high")),     # SK hynix 2Rx4 8 Gb
    ("M393A4K40DB2-CVF", 32, 2, 2933, ("micron-8gb-x4-ddr4-2933", "high")),       # Samsung 2Rx4 8 Gb
    ("M393A2K43BB1-CTD", 16, 2, 2666, ("micron-8gb-x8-ddr4-2666", "high")),       # Samsung 2Rx8 8 Gb
    ("M393A2K43BB1-CTD", 16, 2, 2400, ("micron-8gb-x8-ddr4-2400-b", "high")),     # the same, run at 2400
    ("HMA82GR7AFR8N-XN", 16, 2, 3200, ("micron-8gb-x8-ddr4-3200-g", "high")),     # SK hynix 2Rx8 8 Gb at 3200
    ("MTA36ASF4G72PZ-3G2R1", 32, 2, 3200, ("micron-8gb-x4-ddr4-3200", "high")),   # Micron 2Rx4 8 Gb at 3200
    ("M393A4K40DB3-CWE", 32, 2, 2133, ("micron-8gb-x4-ddr4-2400-b", "medium")),   # no 2133 x4 8 Gb preset
    ("M393A1G40DB0-CPB", 8, 1, 2133, ("micron-4gb-x4-ddr4-2133", "high")),       # Samsung 1Rx4 4 Gb
    ("M393A2G40DB0-CPB", 16, 2, 2133, ("micron-4gb-x4-ddr4-2133", "high")),       # Samsung 2Rx4 4 Gb
    ("HMA42GR7AFR4N-UH", 16, 2, 2400, ("micron-4gb-x4-ddr4-2400", "high")),       # SK hynix 2Rx4 4 Gb
    ("M393A2K40BB1-CRC", 16, 1, 2400, ("micron-8gb-x4-ddr4-2400-b", "high")),     # Samsung 1Rx4 8 Gb
    ("M393A8G40MB2-CVF", 64, 2, 2933, ("micron-8gb-x4-ddr4-2933", "low")),        # 16 Gb x4: no 16 Gb preset
])
def test_dimms_map_to_the_preset_of_their_die(part: str, size_gib: int, ranks: int, speed: int,
                                              expect: tuple[str, str]) -> None:
    """Known modules name their die's preset (exact); else the preset of the same density and width at the
    nearest speed (high, medium), and a stand-in of another density says low."""
    dimm = Dimm("X", size_bytes=size_gib << 30, type="DDR4", speed_mts=speed, ranks=ranks, total_width=72,
                part_number=part)
    choice = choose_memspec([dimm])
    assert (choice.name, choice.confidence) == expect, choice.reason


def test_an_x16_module_gets_the_x16_preset() -> None:
    """A 4 GB 1Rx16 DDR4-2666 UDIMM (Micron MTA4ATF51264AZ: 4 devices per rank -> x16, 8 Gb): the x16 preset,
    re-shaped to 1 rank of 4 devices."""
    dimm = Dimm("DIMM_A1", size_bytes=4 << 30, type="DDR4", speed_mts=2666, ranks=1, total_width=64, data_width=64,
                part_number="MTA4ATF51264AZ-2G6E1")
    choice = choose_memspec([dimm])
    assert (choice.name, choice.confidence, choice.device_width, choice.die_gbit) == \
        ("micron-8gb-x16-ddr4-2666-b", "high", 16, 8)
    spec = for_dimm(preset("micron-8gb-x16-ddr4-2666-b"), choice.ranks, choice.devices_per_rank)
    assert (spec.nbr_of_ranks, spec.nbr_of_devices, spec.nbr_of_banks) == (1, 4, 8)
