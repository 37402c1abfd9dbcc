"""EDAC ``rank*`` directories of chip-select based drivers (issue 29, item 3).

The kernel names a DIMM directory ``rankN`` instead of ``dimmN`` when the driver's layers include
the chip select (``mci->csbased``, amd64_edac); Documentation/ABI/testing/sysfs-devices-edac
documents ``/sys/devices/system/edac/mc/mc*/(dimm|rank)*`` with ``rank*/size`` one rank's size. The
tree (make_fixtures.epyc_ranks) is an EPYC 7302 node with 16 x 32 GB 2Rx4 DIMMs and no dmidecode.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from hdeem_watch.cli import main
from hdeem_watch.node.edac import read_edac


def test_rank_directories_are_joined_into_dimms(node_trees: Path) -> None:
    """32 rank directories of 16 GB → 16 DIMMs of 32 GB with 2 ranks, one per channel of each controller."""
    dimms, note = read_edac(node_trees / "epyc-rome-amd64-edac" / "sys")
    assert len(dimms) == 16
    assert {(d.size_mb, d.ranks, d.dev_type) for d in dimms} == {(32768, 2, "x4")}
    assert sorted((d.mc, d.location["channel"]) for d in dimms) == [(m, c) for m in range(2) for c in range(8)]
    assert "rank*/" in note and "chip-select" in note
    assert dimms[0].name == "rank0+rank8" and dimms[0].label == "mc#0csrow#0channel#0"


def test_a_single_rank_dimm_stays_one_rank(node_trees: Path, tmp_path: Path) -> None:
    """Chip select 1 missing on channel 5: that DIMM is 1 rank of 16 GB; its neighbours keep 2."""
    root = tmp_path / "sys"
    shutil.copytree(node_trees / "epyc-rome-amd64-edac" / "sys", root)
    shutil.rmtree(root / "devices/system/edac/mc/mc0/rank13")        # chip select 1, channel 5
    dimms, _ = read_edac(root)
    by_place = {(d.mc, d.location["channel"]): d for d in dimms}
    assert (by_place[(0, 5)].ranks, by_place[(0, 5)].size_mb) == (1, 16384)
    assert (by_place[(0, 4)].ranks, by_place[(0, 4)].size_mb) == (2, 32768)


def test_node_places_the_edac_dimms_of_a_chip_select_driver(node_trees: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    """Without dmidecode the rank tree gives 8 channels x 1 DIMM per socket, 2 ranks, 8 Gb x4 dies."""
    assert main(["node", "--sysfs-root", str(node_trees / "epyc-rome-amd64-edac" / "sys"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert (out["channels_per_socket"], out["dimms_per_channel"], len(out["dimms"])) == (8, 1, 16)
    assert {(d["ranks"], d["size_bytes"], d["device_width"]) for d in out["dimms"]} == {(2, 32 << 30, 4)}
    assert (out["memspec"]["die_gbit"], out["memspec"]["device_width"]) == (8, 4)
