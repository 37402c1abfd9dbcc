"""The node as public dmidecode captures show it (issue 29, items 1, 2 and 8).

Both captures are excerpts of RRZE-HPC INSPECT machine pages (tests/node/captures/, source in each
header): a Supermicro X11DDW-L with 2 x Xeon Gold 6148 (SNC2), whose bank locators
``P0_Node1_Channel2_Dimm0`` number the memory controller, and a Supermicro X10DRL-i with 2 x Xeon
E5-2695 v3 (Cluster-on-Die), whose bank locators repeat the socket and whose BIOS prints
``Type: Other`` for DDR4 RDIMMs. The sysfs trees are built by make_fixtures.py.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from hdeem_watch.cli import main
from hdeem_watch.node.bank_nodes import bank_node_rule
from hdeem_watch.node.cpu_model import CpuModel, cpu_from_cpuinfo, memory_controller
from hdeem_watch.node.description import Dimm
from hdeem_watch.node.locators import parse_location
from hdeem_watch.node.memory_type import infer_ddr
from hdeem_watch.node.memspec_choice import choose_memspec


def node_json(capsys: pytest.CaptureFixture[str], root: Path, name: str) -> dict[str, Any]:
    argv = ["node", "--sysfs-root", str(root / name / "sys"), "--dmidecode", str(root / name / "dmidecode.txt"),
            "--json"]
    assert main(argv) == 0
    return json.loads(capsys.readouterr().out)


def test_skylake_sp_snc_node_has_six_channels_of_one_dimm(node_trees: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """NodeN varies within a socket: it is the memory controller, so 2 IMCs x 3 channels = 6 channels per
    socket with one DIMM each (it was 3 channels with two DIMMs each when only ChannelN was read)."""
    out = node_json(capsys, node_trees, "skylake-sp-x11ddw-snc2")
    assert (out["sockets"], out["channels_per_socket"], out["dimms_per_channel"]) == (2, 6, 1)
    assert out["numa_nodes_per_socket"] == 2
    places = {d["locator"]: (d["socket"], d["channel"]) for d in out["dimms"]}
    assert len(places) == 12 and len(set(places.values())) == 12
    assert places["P1-DIMMA1"] == (0, 0) and places["P1-DIMMD1"] == (0, 3) and places["P2-DIMMF1"] == (1, 5)
    assert out["channel_rule"].startswith("bank locator NodeN is the memory controller")
    assert "slot letters: 6 per socket agree" in out["channel_rule"]
    assert "Skylake-SP/Cascade Lake-SP: 6 channels per socket agrees" in out["channel_rule"]
    assert out["channel_rule"] in out["facts"]["channels_per_socket"]["source"]
    assert out["model"]["error"] is None and out["model"]["channels_per_domain"] == 3


def test_haswell_ep_type_other_gets_the_ddr4_memspec_of_its_part(node_trees: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    """``Type: Other`` on M393A1G40DB0-CPB (8 GB 1Rx4, 4 Gb x4 dies, 2133) with Xeon E5-2695 v3: DDR4,
    by the part number and the CPU; the memspec is the 4 Gb x4 2133 preset and the reason says why."""
    out = node_json(capsys, node_trees, "haswell-ep-x10drl-cod")
    assert {d["type"] for d in out["dimms"]} == {"Other"}
    memspec = out["memspec"]
    assert (memspec["name"], memspec["confidence"]) == ("micron-4gb-x4-ddr4-2133", "high")
    assert memspec["reason"].startswith("memory type Other read as DDR4: part number M393A1G40DB0-CPB is a "
                                        "Samsung DDR4 module")
    assert "E5-2695 v3 @ 2.30GHz (Haswell-EP) drives DDR4 only" in memspec["reason"]
    assert (out["channels_per_socket"], out["dimms_per_channel"], out["numa_nodes_per_socket"]) == (4, 1, 2)
    assert out["channel_rule"].startswith("bank locator NodeN repeats the socket")
    assert out["cpu"] == {"name": "Intel(R) Xeon(R) CPU E5-2695 v3 @ 2.30GHz", "source": "dmidecode -t 4",
                          "memory_controller": {"generation": "Haswell-EP", "channels_per_socket": 4,
                                                "memory_types": ["DDR4"]}}
    # the letters run on across sockets on this board (P2-DIMME1 is socket 1's first channel)
    first = next(d for d in out["dimms"] if d["locator"] == "P2-DIMME1")
    assert (first["socket"], first["channel"], first["channel_letter"]) == (1, 0, "E")


@pytest.mark.parametrize(("part", "expect"), [
    ("M393A1G40DB0-CPB", "DDR4"), ("M386A4G40DM0-CPB", "DDR4"), ("HMA82GR7AFR8N-VK", "DDR4"),
    ("MTA18ASF2G72PZ-2G3B1", "DDR4"), ("18ASF1G72PDZ-2G6B1", "DDR4"),
    ("M393B2G70BH0-CK0", "DDR3"), ("HMT42GR7AFR4C-RD", "DDR3"), ("18KSF1G72PDZ-1G6E1", "DDR3"),
])
def test_part_number_families(part: str, expect: str) -> None:
    """JEDEC/vendor family prefixes: Samsung M3xxA / SK hynix HMA / Micron (MTA)nnA.F are DDR4."""
    assert infer_ddr("Other", part, None)[0] == expect


def test_the_cpu_alone_says_ddr4_and_a_named_type_is_kept() -> None:
    """An unknown part on an E5 v3 is DDR4 by the CPU; E7 v3 (DDR3 or DDR4) says nothing; DDR4 stays."""
    e5 = cpu_from_cpuinfo("cpu family\t: 6\nmodel\t\t: 63\nmodel name\t: Intel(R) Xeon(R) CPU E5-2680 v3 @ 2.50GHz\n")
    e7 = CpuModel("Intel(R) Xeon(R) CPU E7-8890 v3 @ 2.50GHz", 6, 63, "test")
    ddr, why = infer_ddr("Unknown", "ACME-123", e5)
    assert ddr == "DDR4" and why is not None and "(Haswell-EP) drives DDR4 only" in why
    assert infer_ddr("Unknown", "ACME-123", e7) == ("Unknown", None)
    assert memory_controller(e7) is None
    assert infer_ddr("DDR4", "ACME-123", e5) == ("DDR4", None)


def test_type_other_without_evidence_still_chooses_nothing() -> None:
    """No part family and no CPU: the type stays unknown and no DDR4 preset is claimed."""
    dimm = Dimm("P1-DIMMA1", size_bytes=8 << 30, type="Other", speed_mts=2133, ranks=1, total_width=72,
                part_number="ACME-123")
    assert choose_memspec([dimm]).name is None


def test_letters_that_disagree_are_named() -> None:
    """A board whose slot letters say 4 channels while NodeN x ChannelN gives 6: the rule says so."""
    guesses = [parse_location(f"P1-DIMM{'ABCD'[i % 4]}1", f"P0_Node{i // 3}_Channel{i % 3}_Dimm0") for i in range(6)]
    rule = bank_node_rule(guesses, None)
    assert rule is not None and rule.node_is_controller
    assert "slot letters: 4 per socket disagree" in rule.text


def test_sixteen_gbit_dies_get_the_nearest_preset_as_a_prior() -> None:
    """64 GB 2Rx4 at 2933: 16 Gb dies, for which no preset exists; the nearest one is the calibration's
    prior, and the reason says so (issue 29, item 8)."""
    dimm = Dimm("P1-DIMMA1", size_bytes=64 << 30, type="DDR4", speed_mts=2933, ranks=2, total_width=72,
                part_number="M393A8G40AB2-CWE")
    choice = choose_memspec([dimm])
    assert choice.die_gbit == 16 and choice.confidence == "low"
    assert choice.name == "micron-8gb-x4-ddr4-2933"
    assert f"16 Gb dies have no preset (no complete public IDD table): {choice.name} is only the calibration's " \
           "prior" in choice.reason
