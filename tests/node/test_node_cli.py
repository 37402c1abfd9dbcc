"""``hdeem-watch node`` on fixture trees of real machine generations (issue 15).

Each fixture (<node>/ of the session's node_trees, built by make_fixtures.py) is a sysfs subset as Linux
lays it out (cpu/cpuN/topology, node/nodeN/cpulist, edac/mc/mcN/dimmM; kernel
Documentation/ABI/testing/sysfs-devices-edac) and a ``dmidecode -t 17`` print-out in the spelling
of the dmidecode version such a node ran (2.12: "8192 MB", "MHz", "Configured Clock Speed"; 3.2+:
"GB", "MT/s", "Configured Memory Speed"). The expected values below are the machines' facts.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from hdeem_watch.cli import main

#: node -> (sockets, cores/socket, threads/core, NUMA/socket, channels/socket, DIMMs/channel, DIMMs,
#:          size GiB, ranks, MT/s rated, part number, memspec, confidence)
EXPECTED: dict[str, tuple[Any, ...]] = {
    "haswell-ep-taurus": (2, 12, 2, 1, 4, 1, 8, 8, 2, 2133, "M393A1G43DB0-CPB", "samsung-m393a1g43db0-cpb", "exact"),
    "skylake-sp": (2, 20, 2, 1, 6, 1, 12, 16, 2, 2666, "M393A2K43BB1-CTD", "micron-8gb-x8-ddr4-2666", "high"),
    "skylake-sp-snc2": (2, 20, 2, 2, 6, 1, 12, 16, 2, 2666, "M393A2K43BB1-CTD", "micron-8gb-x8-ddr4-2666", "high"),
    "icelake-sp-2dpc": (2, 28, 2, 1, 8, 2, 32, 32, 2, 3200, "MTA36ASF4G72PZ-3G2R1", "micron-8gb-x4-ddr4-2933", "high"),
    "epyc-rome-8ch": (2, 16, 2, 1, 8, 1, 16, 32, 2, 2933, "M393A4K40DB2-CVF", "micron-8gb-x4-ddr4-2933", "high"),
    "one-socket-skylake": (1, 12, 2, 1, 6, 1, 6, 16, 2, 2666, "HMA82GR7AFR8N-VK", "micron-8gb-x8-ddr4-2400-b", "high"),
}


def _run_json(capsys: pytest.CaptureFixture[str], *argv: str) -> dict[str, Any]:
    assert main(["node", *argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def _fixture_args(root: Path, name: str) -> tuple[str, ...]:
    return ("--sysfs-root", str(root / name / "sys"), "--dmidecode", str(root / name / "dmidecode.txt"))


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_fixture_node_json(node_trees: Path, capsys: pytest.CaptureFixture[str], name: str) -> None:
    """--json gives the machine's sockets, cores, NUMA, channels, DIMMs per channel, DIMMs and memspec."""
    (sockets, cores, threads, numa, channels, dpc, count, size_gib, ranks, speed, part, memspec,
     confidence) = EXPECTED[name]
    out = _run_json(capsys, *_fixture_args(node_trees, name))
    assert (out["sockets"], out["cores_per_socket"], out["threads_per_core"], out["numa_nodes_per_socket"],
            out["channels_per_socket"], out["dimms_per_channel"]) == (sockets, cores, threads, numa, channels, dpc)
    dimms = out["dimms"]
    assert len(dimms) == count
    assert {d["size_bytes"] for d in dimms} == {size_gib << 30}
    assert {(d["type"], d["speed_mts"], d["ranks"], d["part_number"]) for d in dimms} == {("DDR4", speed, ranks, part)}
    # every DIMM placed, every (socket, channel, slot) once, channels per socket as expected
    places = {(d["socket"], d["channel"], d["slot"]) for d in dimms}
    assert len(places) == count
    assert {d["socket"] for d in dimms} == set(range(sockets))
    assert {d["channel"] for d in dimms} == set(range(channels))
    assert out["memspec"]["name"] == memspec and out["memspec"]["confidence"] == confidence
    assert out["memspec"]["reason"]
    for fact in out["facts"].values():
        assert fact["source"] and not fact["source"].startswith("unknown"), fact


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_sensor_map(node_trees: Path, capsys: pytest.CaptureFixture[str], name: str) -> None:
    """RAPL DRAM<N> holds socket N's DIMMs; HDEEM-style pairs hold two consecutive channels of one socket."""
    out = _run_json(capsys, *_fixture_args(node_trees, name))
    by_locator = {d["locator"]: d for d in out["dimms"]}
    sockets, channels = out["sockets"], out["channels_per_socket"]
    for s in range(sockets):
        assert sorted(out["sensors"][f"DRAM{s}"]) == sorted(d["locator"] for d in out["dimms"] if d["socket"] == s)
    pairs = {k: v for k, v in out["sensors"].items() if k.startswith("DDR_")}
    assert len(pairs) == sockets * channels // 2
    for sensor, locators in pairs.items():
        letters = sensor.removeprefix("DDR_")
        assert {by_locator[x]["channel_letter"] for x in locators} == set(letters)
        assert len({by_locator[x]["socket"] for x in locators}) == 1
    assert sorted(x for v in pairs.values() for x in v) == sorted(by_locator)


def test_taurus_sensor_map_is_hdeems(node_trees: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """On the Taurus node: DDR_AB = socket 0 channels A, B ... DDR_GH = socket 1's last two channels."""
    out = _run_json(capsys, *_fixture_args(node_trees, "haswell-ep-taurus"))
    assert out["sensors"]["DDR_AB"] == ["P1-DIMMA1", "P1-DIMMB1"]
    assert out["sensors"]["DDR_CD"] == ["P1-DIMMC1", "P1-DIMMD1"]
    assert out["sensors"]["DDR_EF"] == ["P2-DIMMA1", "P2-DIMMB1"]
    assert out["sensors"]["DDR_GH"] == ["P2-DIMMC1", "P2-DIMMD1"]
    assert out["sensors"]["DRAM1"] == ["P2-DIMMA1", "P2-DIMMB1", "P2-DIMMC1", "P2-DIMMD1"]
    assert out["cpus_by_socket"]["0"] == [*range(12), *range(24, 36)]
    dimm = out["dimms"][0]
    assert dimm["configured_mts"] == 2133 and dimm["total_width"] == 72 and dimm["device_width"] == 8
    assert dimm["sources"]["device_width"].startswith("edac")
    assert dimm["sources"]["part_number"] == "dmidecode -t 17"


def test_edac_alone_places_the_dimms(node_trees: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Without dmidecode (not root), the EDAC labels give socket and channel of every populated DIMM."""
    out = _run_json(capsys, "--sysfs-root", str(node_trees / "icelake-sp-2dpc" / "sys"))
    assert (out["channels_per_socket"], out["dimms_per_channel"], len(out["dimms"])) == (8, 2, 32)
    assert out["facts"]["channels_per_socket"]["source"].startswith("edac")
    assert {d["device_width"] for d in out["dimms"]} == {4}
    assert any("dmidecode" in note for note in out["notes"])
    assert out["memspec"]["confidence"] == "low"     # no part number, no ranks: density unknown


def test_text_output_and_notes(node_trees: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The table names the memspec, its confidence and reason, the sensors and what was not detected."""
    assert main(["node", *_fixture_args(node_trees, "epyc-rome-8ch")]) == 0
    text = capsys.readouterr().out
    assert "memspec: micron-8gb-x4-ddr4-2933  [high]" in text
    assert "P1 CHANNEL H DIMM 0" in text and "DRAM1" in text
    assert "no EDAC driver loaded" in text


@pytest.mark.slow
def test_this_machine_says_what_it_cannot_detect() -> None:
    """On the live machine (here a VM) the command exits 0 and lists what it could not detect, and why."""
    done = subprocess.run([sys.executable, "-m", "hdeem_watch", "node", "--json"], capture_output=True, text=True,
                          timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    assert out["sockets"] is None or out["sockets"] >= 1
    if not out["dimms"]:
        assert out["notes"] and out["memspec"]["name"] is None
        assert out["facts"]["channels_per_socket"]["source"].startswith("unknown")


def test_config_fills_what_a_vm_cannot_see(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The [node] table sets channels and DIMMs where nothing is detected; its facts say so."""
    config = tmp_path / "daemon.toml"
    config.write_text('[node]\nsockets = 2\nchannels_per_socket = 4\ndimms_per_channel = 1\n'
                      '[node.dimm]\npart_number = "M393A1G43DB0-CPB"\nsize_gb = 8\nranks = 2\n')
    out = _run_json(capsys, "--sysfs-root", str(tmp_path), "--config", str(config))
    assert (out["sockets"], out["channels_per_socket"], len(out["dimms"])) == (2, 4, 8)
    assert out["facts"]["sockets"]["source"] == "config [node]"
    assert out["memspec"]["name"] == "samsung-m393a1g43db0-cpb"
    assert out["sensors"]["DDR_GH"] == ["S1-C1", "S1-D1"]


@pytest.mark.parametrize(("argv", "expect"), [
    (["--sysfs-root", "/nonexistent/dir"], "--sysfs-root /nonexistent/dir: not a directory"),
    (["--dmidecode", "/nonexistent/dmi.txt"], "--dmidecode /nonexistent/dmi.txt: cannot read"),
])
def test_bad_input_exits_2(capsys: pytest.CaptureFixture[str], argv: list[str], expect: str) -> None:
    """A missing directory or file is one line naming it, exit code 2."""
    assert main(["node", *argv]) == 2
    err = capsys.readouterr().err
    assert expect in err and err.count("\n") == 1


def test_bad_config_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """An unknown [node] key is named with the file."""
    config = tmp_path / "bad.toml"
    config.write_text("[node]\nsocket = 2\n")
    assert main(["node", "--sysfs-root", str(tmp_path), "--config", str(config)]) == 2
    assert "bad.toml: [node]: unknown key 'socket'" in capsys.readouterr().err
