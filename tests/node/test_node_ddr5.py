"""``hdeem-watch node`` on DDR5 nodes: Sapphire Rapids (RAPL DRAM per socket) and Genoa (no DRAM sensor).

The fixtures (sapphire-rapids-2s, genoa-2s of the session's node_trees, built by make_fixtures.py, which
cites the facts) are sysfs subsets with a ``class/powercap`` tree and a ``dmidecode`` print-out with the
processor (type 4) and memory device (type 17) records of DDR5 RDIMMs.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from hdeem_watch.cli import main
from hdeem_watch.node.cpu_model import CpuModel, cpu_from_cpuinfo, is_amd, memory_controller
from hdeem_watch.node.memory_type import infer_ddr

REPO = Path(__file__).resolve().parents[2]


def node_json(capsys: pytest.CaptureFixture[str], root: Path, name: str, *extra: str) -> dict[str, Any]:
    argv = ["node", "--sysfs-root", str(root / name / "sys"), "--dmidecode", str(root / name / "dmidecode.txt"),
            *extra, "--json"]
    assert main(argv) == 0
    return json.loads(capsys.readouterr().out)


def test_sapphire_rapids_node(node_trees: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """2 sockets x 8 DDR5 channels, 16 DDR5 DIMMs placed once each, RAPL DRAM0/DRAM1 zones as the sensors."""
    out = node_json(capsys, node_trees, "sapphire-rapids-2s")
    assert (out["sockets"], out["cores_per_socket"], out["channels_per_socket"], out["dimms_per_channel"]) == (2, 56, 8, 1)
    dimms = out["dimms"]
    assert len(dimms) == 16 and {d["type"] for d in dimms} == {"DDR5"}
    assert {(d["size_bytes"], d["ranks"], d["speed_mts"], d["total_width"]) for d in dimms} == {(32 << 30, 2, 4800, 80)}
    assert len({(d["socket"], d["channel"]) for d in dimms}) == 16
    assert out["cpu"]["memory_controller"] == {"generation": "Sapphire Rapids", "channels_per_socket": 8,
                                               "memory_types": ["DDR5"]}
    energy = out["dram_energy"]
    assert energy["sensor"] == "rapl" and energy["model"] is None
    assert sorted(energy["zones"]) == ["DRAM0", "DRAM1"]
    for s in range(2):
        assert sorted(out["sensors"][f"DRAM{s}"]) == sorted(d["locator"] for d in dimms if d["socket"] == s)
    assert out["model"]["error"] is None and out["model"]["dimms"] == 16


def test_ddr5_memspec_is_not_invented(node_trees: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """No DDR5 preset: no name, confidence none, the dies worked out, and the way in (a DDR5 memspec file)."""
    memspec = node_json(capsys, node_trees, "sapphire-rapids-2s")["memspec"]
    assert memspec["name"] is None and memspec["confidence"] == "none"
    assert (memspec["die_gbit"], memspec["device_width"], memspec["devices_per_rank"]) == (16, 8, 10)
    reason = memspec["reason"]
    assert "no DDR5 preset" in reason and "--memspec" in reason and "[node]" in reason
    assert "examples/ddr5_drampower_test.json" in reason and (REPO / "examples/ddr5_drampower_test.json").is_file()


def test_genoa_node(node_trees: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """2 sockets x 12 DDR5 channels, 24 DIMMs; no DRAM sensor: the energy is modelled from amd_umc counts."""
    out = node_json(capsys, node_trees, "genoa-2s")
    assert (out["sockets"], out["cores_per_socket"], out["channels_per_socket"], out["dimms_per_channel"]) == (2, 96, 12, 1)
    dimms = out["dimms"]
    assert len(dimms) == 24 and {d["type"] for d in dimms} == {"DDR5"}
    assert {d["channel"] for d in dimms} == set(range(12)) and {d["socket"] for d in dimms} == {0, 1}
    assert (out["memspec"]["die_gbit"], out["memspec"]["device_width"]) == (16, 4)
    assert out["cpu"]["memory_controller"]["generation"] == "Genoa (EPYC 9004)"
    energy = out["dram_energy"]
    assert energy["sensor"] is None and energy["zones"] == {} and "amd_umc" in energy["model"]
    assert "no DRAM energy sensor" in energy["how"] and energy["currents"].startswith("none")
    assert out["sensors"] == {}


def test_genoa_with_a_ddr5_memspec_says_which_currents(node_trees: Path, capsys: pytest.CaptureFixture[str],
                                                       tmp_path: Path) -> None:
    """A memspec file in the [node] table: the modelled energy names it as the source of the currents."""
    config = tmp_path / "node.toml"
    config.write_text('[node]\nmemspec = "examples/ddr5_drampower_test.json"\n')
    out = node_json(capsys, node_trees, "genoa-2s", "--config", str(config))
    assert out["memspec"]["confidence"] == "configured"
    assert out["dram_energy"]["currents"].startswith("memspec file examples/ddr5_drampower_test.json")


def test_genoa_text_names_the_model(node_trees: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The text report says there is no DRAM sensor and what models the energy."""
    name = "genoa-2s"
    assert main(["node", "--sysfs-root", str(node_trees / name / "sys"),
                 "--dmidecode", str(node_trees / name / "dmidecode.txt")]) == 0
    text = capsys.readouterr().out
    assert "(none: no DRAM sensor)" in text and "DRAM energy: none; modelled: amd_umc" in text


@pytest.mark.parametrize(("name", "family", "model", "generation", "channels"), [
    ("Intel(R) Xeon(R) Platinum 8480+", 6, 143, "Sapphire Rapids", 8),
    ("INTEL(R) XEON(R) PLATINUM 8592+", 6, 207, "Emerald Rapids", 8),
    ("Intel(R) Xeon(R) 6980P", 6, 173, "Granite Rapids-AP (Xeon 6900P)", 12),
    ("Intel(R) Xeon(R) 6787P", 6, 173, "Granite Rapids-SP (Xeon 6700P/6500P)", 8),
    ("AMD EPYC 9654 96-Core Processor", 25, 17, "Genoa (EPYC 9004)", 12),
    ("AMD EPYC 9755 128-Core Processor", 26, 2, "Turin (EPYC 9005)", 12),
    ("AMD EPYC 8534P 64-Core Processor", 25, 160, "Siena (EPYC 8004)", 6),
])
def test_ddr5_memory_controllers(name: str, family: int, model: int, generation: str, channels: int) -> None:
    """Each DDR5 CPU's memory controller: its generation and DDR5 channels per socket."""
    controller = memory_controller(CpuModel(name, family, model, "test"))
    assert controller is not None
    assert (controller.generation, controller.channels_per_socket, controller.memory_types) == (generation, channels,
                                                                                                 ("DDR5",))
    assert is_amd(CpuModel(name, family, model, "test")) == name.startswith("AMD")


def test_ddr5_read_from_part_number_and_cpu() -> None:
    """``Type: Other``: a Micron MTC part number and a Genoa CPU each say DDR5."""
    genoa = cpu_from_cpuinfo("vendor_id : AuthenticAMD\ncpu family : 25\nmodel : 17\n"
                             "model name : AMD EPYC 9654 96-Core Processor\n")
    ddr, why = infer_ddr("Other", "MTC20F2085S1RC48BA1", genoa)
    assert ddr == "DDR5" and why is not None and "Micron DDR5" in why and "drives DDR5 only" in why
    assert infer_ddr("Unknown", "M321R4GA3BB6-CQK", None)[0] == "DDR5"


def test_granite_rapids_tpmi_zones_are_the_sensor(powercap_trees: Path) -> None:
    """A Granite Rapids node whose DRAM zones come from Intel's TPMI driver (intel-rapl-tpmi:<n>:0): RAPL."""
    from hdeem_watch.node.dram_energy import detect_dram_energy

    gnr = CpuModel("Intel(R) Xeon(R) 6980P", 6, 173, "test")
    energy = detect_dram_energy(powercap_trees / "powercap_gnr_tpmi", gnr)
    assert energy.sensor == "rapl" and sorted(energy.zones) == ["DRAM0", "DRAM1"]
    assert "intel-rapl-tpmi" in energy.how and energy.zones["DRAM1"].endswith("intel-rapl-tpmi:2:0")
    missing = detect_dram_energy(powercap_trees / "powercap_gnr_tpmi_nodram", gnr)
    assert missing.sensor is None and missing.model is None and "no zone named 'dram'" in missing.how
