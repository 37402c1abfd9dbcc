"""DDR5 memspec reader (as DRAMPower v6.2 reads it) and its physical check."""

from __future__ import annotations

import copy
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from hdeem_watch.dram.memspec_ddr5 import is_ddr5, load_memspec_ddr5, parse_memspec_ddr5
from hdeem_watch.dram.memspec_ddr5_check import physical_violations_ddr5
from hdeem_watch.errors import InputError

REPO = Path(__file__).resolve().parents[2]
TOY = REPO / "examples" / "ddr5_drampower_test.json"


@pytest.fixture
def toy() -> dict[str, Any]:
    """DRAMPower's DDR5 test memspec as a parsed JSON tree (a fresh copy per test)."""
    return json.loads(TOY.read_text())


def test_reads_what_drampower_uses(toy: dict[str, Any]) -> None:
    """Timings, refresh mode, burst from the spec, devices 0 -> 1 (as DRAMPower's MemSpec does)."""
    spec = parse_memspec_ddr5(toy, "toy")
    assert (spec.nbr_of_ranks, spec.nbr_of_devices, spec.nbr_of_banks, spec.banks_per_group) == (1, 1, 16, 8)
    assert (spec.burst_length, spec.data_rate, spec.burst_cycles) == (8, 2, 4.0)
    assert (spec.trfc, spec.trfcsb, spec.refresh_currents) == (25, 20, ("idd5b", "ipp5b"))
    assert spec.currents["ibeta_vdd"] == 0.05625 and spec.fact_rho == 0.5
    toy["memspec"]["memarchitecturespec"].update(RefMode=2, nbrOfDevices=0)
    spec = parse_memspec_ddr5(toy, "toy")
    assert (spec.trfc, spec.refresh_currents, spec.nbr_of_devices) == (30, ("idd5f", "ipp5f"), 1)


def test_write_back_is_read_back(toy: dict[str, Any], tmp_path: Path) -> None:
    """with_currents + to_json_dict: DRAMPower's JSON with only the changed current replaced."""
    spec = parse_memspec_ddr5(toy, "toy").with_currents({"idd5c": 0.09})
    tree = spec.to_json_dict()
    expected = copy.deepcopy(toy)
    expected["memspec"]["mempowerspec"]["idd5c"] = 0.09
    assert tree == expected
    path = tmp_path / "m.json"
    path.write_text(json.dumps(tree))
    assert load_memspec_ddr5(path).currents == spec.currents


@pytest.mark.parametrize(("edit", "message"), [
    (lambda s: s.update(memoryType="DDR4"), r"memoryType = 'DDR4'; expected 'DDR5'"),
    (lambda s: s["memtimingspec"].pop("RFCsb_slr"), r"memtimingspec: missing field RFCsb_slr"),
    (lambda s: s["memtimingspec"].pop("REFI1"), r"memtimingspec: missing field REFI1"),
    (lambda s: s["mempowerspec"].pop("idd5f"), r"mempowerspec: missing field idd5f"),
    (lambda s: s["mempowerspec"].update(idd5c=110.0), r"idd5c = 110.0 looks like mA; expected amperes"),
    (lambda s: s["memarchitecturespec"].update(RefMode=4), r"RefMode = 4: expected 1 or 2"),
    (lambda s: s["memarchitecturespec"].update(nbrOfBankGroups=3), r"not a multiple of nbrOfBankGroups = 3"),
    (lambda s: s["memtimingspec"].update(tCK=0.77), r"tCK = 0.77 looks like ns"),
    (lambda s: s["memtimingspec"].update(RAS=0), r"RAS = 0: expected a positive integer"),
    (lambda s: s.pop("memimpedancespec"), r"memimpedancespec: missing section"),
])
def test_bad_fields_are_one_line_errors(toy: dict[str, Any], edit: Any, message: str) -> None:
    edit(toy["memspec"])
    with pytest.raises(InputError, match=message) as caught:
        parse_memspec_ddr5(toy, "m.json")
    assert "\n" not in str(caught.value) and str(caught.value).startswith("m.json")


def test_is_ddr5(toy: dict[str, Any]) -> None:
    assert is_ddr5(toy)
    toy["memspec"]["memoryType"] = "DDR4"
    assert not is_ddr5(toy) and not is_ddr5([1]) and not is_ddr5({"memspec": 3})


def test_physical_rules_of_ddr5(toy: dict[str, Any]) -> None:
    """Same-bank refresh below I_BG and the DDR4 rules (per supply) are reported; the toy is physical."""
    spec = parse_memspec_ddr5(toy, "toy")
    assert physical_violations_ddr5(spec) == []
    bad = spec.with_currents({"idd5c": 0.036, "ipp3n": 0.001, "ipp4r": 0.0})
    problems = physical_violations_ddr5(bad)
    assert problems[0].startswith("same-bank refresh: IDD5C 36 mA < I_BG")
    assert any(p.startswith("read: IPP4R 0 mA < IPP3N 1 mA") for p in problems)
    toy["memspec"]["mempowerspec"]["idd5c"] = 0.036
    with pytest.raises(InputError, match=r"unphysical currents.*same-bank refresh"):
        parse_memspec_ddr5(toy, "toy")
    assert parse_memspec_ddr5(toy, "toy", allow_unphysical=True).currents["idd5c"] == 0.036


@pytest.mark.slow
def test_cli_refuses_unphysical_ddr5_with_one_line(toy: dict[str, Any], tmp_path: Path) -> None:
    """``model energy`` on an unphysical DDR5 file: exit 2, one line; --allow-unphysical computes."""
    toy["memspec"]["mempowerspec"]["idd5c"] = 0.036
    memspec = tmp_path / "bad.json"
    memspec.write_text(json.dumps(toy))
    trace = tmp_path / "t.csv"
    trace.write_text("0,REFSB,0,0,0,0,0\n100,END,0,0,0,0,0\n")
    args = [sys.executable, "-m", "hdeem_watch", "model", "energy", "--memspec", str(memspec), "--trace", str(trace)]
    done = subprocess.run([*args, "--json"], capture_output=True, text=True)
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and "same-bank refresh" in done.stderr
    done = subprocess.run([*args, "--json", "--allow-unphysical"], capture_output=True, text=True, check=True)
    assert json.loads(done.stdout)["components"]["refsb_j"] < 0
