"""DRAMPower DDR4 memspecs: round trip, validation errors, presets."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hdeem_watch.dram.memspec import load_memspec, parse_memspec, preset, save_memspec
from hdeem_watch.errors import InputError


def test_reference_memspecs_round_trip_unchanged(drampower_ref: Path, tmp_path: Path) -> None:
    """Loading then saving a DRAMPower memspec writes back the same JSON tree (every field)."""
    for path in sorted((drampower_ref / "memspecs").glob("*.json")):
        original = json.loads(path.read_text())
        spec = load_memspec(path)
        out = tmp_path / path.name
        save_memspec(spec, out)
        assert json.loads(out.read_text()) == original, path.name
        assert load_memspec(out) == spec


def test_fields_in_si_units(reference_memspec_path) -> None:  # type: ignore[no-untyped-def]
    """Parsed values keep DRAMPower's SI units: A per device, V, tCK in s, timings in cycles."""
    spec = load_memspec(reference_memspec_path("allterms"))
    assert spec.tck_s == pytest.approx(0.9375e-9)
    assert (spec.timings["RAS"], spec.timings["RP"], spec.trfc) == (36, 15, 278)
    assert spec.currents["idd0"] == 0.0585 and spec.currents["ipp5b"] == 0.02
    assert spec.currents["ibeta_vdd"] == 0.05 and spec.fact_rho == 0.5
    assert (spec.vdd, spec.vpp, spec.vddq) == (1.2, 2.5, 1.2)
    assert spec.nbr_of_banks == 16 and spec.nbr_of_ranks == 2 and spec.burst_cycles == 4


def test_unknown_sections_and_fields_preserved(reference_memspec_json, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """Extra sections and fields the model does not know survive a calibrated write-back."""
    data = reference_memspec_json
    data["memspec"]["vendorNotes"] = {"lot": "A17", "tested": True}
    data["memspec"]["mempowerspec"]["iddX_custom"] = 0.5
    spec = parse_memspec(data, "x.json").with_currents({"idd0": 0.05, "idd3n": 0.04})
    save_memspec(spec, tmp_path / "cal.json")
    back = json.loads((tmp_path / "cal.json").read_text())["memspec"]
    assert back["vendorNotes"] == {"lot": "A17", "tested": True}
    assert back["mempowerspec"]["iddX_custom"] == 0.5
    assert back["mempowerspec"]["idd0"] == 0.05 and back["mempowerspec"]["idd3n"] == 0.04
    assert back["mempowerspec"]["idd2n"] == data["memspec"]["mempowerspec"]["idd2n"]
    assert "iBeta_vdd" not in back["mempowerspec"]  # not invented when the source had none
    assert load_memspec(tmp_path / "cal.json").currents["idd0"] == 0.05


def _error(data: dict, where: str = "bad.json") -> str:
    with pytest.raises(InputError) as info:
        parse_memspec(data, where)
    message = str(info.value)
    assert "\n" not in message and message.startswith(where)
    return message


@pytest.mark.parametrize(("section", "key", "value", "expect"), [
    ("mempowerspec", "idd0", 58.5, "idd0 = 58.5 looks like mA"),
    ("mempowerspec", "ipp0", -0.001, "ipp0"),
    ("mempowerspec", "idd3n", "41.75", "idd3n"),
    ("mempowerspec", "vdd", 1200, "vdd = 1200 looks like mV"),
    ("memtimingspec", "RAS", -36, "RAS = -36"),
    ("memtimingspec", "RCD", 15.5, "RCD = 15.5: expected an integer"),
    ("memtimingspec", "tCK", 0.9375, "tCK = 0.9375 looks like ns"),
    ("memarchitecturespec", "nbrOfBanks", 0, "nbrOfBanks = 0"),
    ("memarchitecturespec", "nbrOfRanks", True, "nbrOfRanks"),
    ("memarchitecturespec", "RefMode", 3, "RefMode = 3"),
])
def test_bad_values_named(reference_memspec_json, section: str, key: str, value: object, expect: str) -> None:  # type: ignore[no-untyped-def]
    """A wrong value (mA for A, negative timing, wrong type, ns for s) is one line naming file and field."""
    reference_memspec_json["memspec"][section][key] = value
    assert expect in _error(reference_memspec_json)


@pytest.mark.parametrize(("section", "key"), [
    ("mempowerspec", "idd4w"), ("mempowerspec", "ipp5B"), ("mempowerspec", "vpp"),
    ("memtimingspec", "RFC1"), ("memtimingspec", "tCK"), ("memarchitecturespec", "nbrOfDevices"),
])
def test_missing_field_named(reference_memspec_json, section: str, key: str) -> None:  # type: ignore[no-untyped-def]
    """A missing required field is reported with its section and name."""
    del reference_memspec_json["memspec"][section][key]
    message = _error(reference_memspec_json)
    assert f"memspec.{section}" in message and key in message and "missing" in message


def test_missing_section_and_wrong_type(reference_memspec_json) -> None:  # type: ignore[no-untyped-def]
    """A missing section, a non-DDR4 memspec and a non-object are rejected by name."""
    data = json.loads(json.dumps(reference_memspec_json))
    del data["memspec"]["mempowerspec"]
    assert "mempowerspec: missing section" in _error(data)
    data = json.loads(json.dumps(reference_memspec_json))
    data["memspec"]["memoryType"] = "LPDDR4"
    assert "expected 'DDR4'" in _error(data)
    assert "expected a JSON object" in _error([1, 2])  # type: ignore[arg-type]


def test_refresh_mode_currents_required_when_selected(reference_memspec_json) -> None:  # type: ignore[no-untyped-def]
    """RefMode 2 uses RFC2 and idd5F2/ipp5F2, which must then be present."""
    data = reference_memspec_json
    data["memspec"]["memarchitecturespec"]["RefMode"] = 2
    data["memspec"]["mempowerspec"]["idd5F2"] = 0.080  # the selected refresh current must be physical
    spec = parse_memspec(data, "x")
    assert spec.trfc == 171 and spec.refresh_currents == ("idd5f2", "ipp5f2")
    del data["memspec"]["mempowerspec"]["idd5F2"]
    assert "idd5F2" in _error(data)


def test_load_errors_are_one_line(tmp_path: Path) -> None:
    """Unreadable files and invalid JSON are InputErrors naming the file."""
    with pytest.raises(InputError, match="cannot read memspec"):
        load_memspec(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text('{"memspec": {')
    with pytest.raises(InputError, match=r"bad.json: invalid JSON at line 1"):
        load_memspec(bad)


def test_with_currents_validates_and_is_a_copy() -> None:
    """with_currents returns a new spec, rejects unknown names and mA values, keeps the original."""
    spec = preset("ddr4-2133-x8-4gb")
    cal = spec.with_currents({"IDD0": 0.03, "ibeta_vdd": 0.02})
    assert cal.currents["idd0"] == 0.03 and cal.currents["ibeta_vdd"] == 0.02
    assert spec.currents["idd0"] == 0.0585 and "ibeta_vdd" not in spec.currents
    assert cal.to_json_dict()["memspec"]["mempowerspec"]["iBeta_vdd"] == 0.02
    with pytest.raises(InputError, match="unknown current"):
        spec.with_currents({"idd9": 0.1})
    with pytest.raises(InputError, match="looks like mA"):
        spec.with_currents({"idd2n": 36.0})


def test_presets(drampower_ref: Path) -> None:
    """The reference preset equals the 8-device reference file; the Samsung RDIMM is 2 x 9 x8 4 Gb."""
    ref = preset("ddr4-2133-x8-4gb")
    assert ref == load_memspec(drampower_ref / "memspecs" / "ddr4_2133_x8_2r_8dev.json")
    samsung = preset("samsung-m393a1g43db0-cpb")
    assert (samsung.nbr_of_ranks, samsung.nbr_of_devices, samsung.width) == (2, 9, 8)
    gbit = samsung.nbr_of_banks * samsung.nbr_of_rows * samsung.nbr_of_columns * samsung.width / 2**30
    assert gbit == 4
    assert (samsung.timings["RCD"], samsung.timings["RP"], samsung.timings["RL"]) == (15, 15, 15)
    # per device: see test_samsung_preset_follows_the_module_definition
    with pytest.raises(InputError, match="unknown memspec preset"):
        preset("ddr3-1600")


def test_hashable_and_equal_by_value() -> None:
    """Specs can key caches: equal specs hash equal, a calibrated copy differs."""
    a, b = preset("ddr4-2133-x8-4gb"), preset("ddr4-2133-x8-4gb")
    assert a == b and hash(a) == hash(b)
    cal = a.with_currents({"idd0": 0.03})
    assert cal != a
    assert len({a, b, cal}) == 2


# --- physical check (issue 15) -------------------------------------------------------------------

def test_presets_are_physical() -> None:
    """Every preset passes the physical check (it is applied on load, so loading is the test)."""
    from hdeem_watch.dram.memspec_check import physical_violations
    from hdeem_watch.dram.presets import PRESETS

    for name in PRESETS:
        assert physical_violations(preset(name)) == [], name


def test_samsung_preset_follows_the_module_definition() -> None:
    """Per device = module figure by the dual-rank module definition (DIMM docstring), not module / 18."""
    samsung = preset("samsung-m393a1g43db0-cpb")
    cur = samsung.currents
    # standby figures: all 18 dies in the state
    assert cur["idd2n"] * 18 == pytest.approx(1.040) and cur["idd3n"] * 18 == pytest.approx(1.540)
    # operating figures: one rank (9 dies) in the state, the other rank in IDD2P
    for name, module in (("idd0", 1.120), ("idd4r", 1.750), ("idd4w", 1.590)):
        assert 9 * cur[name] + 9 * cur["idd2p"] == pytest.approx(module), name
    assert cur["idd0"] > cur["idd3n"] > cur["idd2n"]


@pytest.mark.parametrize(("changes", "expect"), [
    ({"idd0": 0.040}, "activation: IDD0 40 mA < I1 41.75 mA"),
    ({"idd0": 0.040}, "ACT+PRE: IDD0 40 mA < the tRAS/tRC mix of IDD3N and IDD2N"),
    ({"idd4r": 0.030}, "read: IDD4R 30 mA < IDD3N 41.75 mA"),
    ({"idd4w": 0.030}, "write: IDD4W 30 mA < IDD3N 41.75 mA"),
    ({"idd5B": 0.030}, "refresh: IDD5B 30 mA < IDD3N 41.75 mA"),
    ({"idd2n": 0.050}, "background: IDD3N 41.75 mA < IDD2N 50 mA"),
    ({"idd2p": 0.040}, "power-down: IDD2P 40 mA > IDD2N 36 mA"),
    ({"idd3p": 0.050}, "power-down: IDD3P 50 mA > IDD3N 41.75 mA"),
    ({"ipp4r": 0.001, "ipp3n": 0.002}, "read: IPP4R 1 mA < IPP3N 2 mA"),
])
def test_unphysical_currents_named(reference_memspec_json, changes: dict, expect: str) -> None:  # type: ignore[no-untyped-def]
    """A current order that makes a command's energy negative is an error naming the currents."""
    reference_memspec_json["memspec"]["mempowerspec"].update(changes)
    message = _error(reference_memspec_json)
    assert "unphysical currents" in message and expect in message
    assert "allow_unphysical" in message


def test_allow_unphysical_loads_a_raw_fit(reference_memspec_json, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """allow_unphysical loads the same file (for studying a fit's raw output) in every loader."""
    from hdeem_watch.dram.memspec import memspec_from

    reference_memspec_json["memspec"]["mempowerspec"]["idd0"] = 0.030
    path = tmp_path / "fit.json"
    path.write_text(json.dumps(reference_memspec_json))
    with pytest.raises(InputError, match="activation"):
        load_memspec(path)
    with pytest.raises(InputError, match="activation"):
        memspec_from(str(path))
    assert load_memspec(path, allow_unphysical=True).currents["idd0"] == 0.030
    assert memspec_from(str(path), allow_unphysical=True).currents["idd0"] == 0.030
    assert parse_memspec(reference_memspec_json, "x", allow_unphysical=True).currents["idd0"] == 0.030


def test_explicit_beta_and_rho_enter_the_check(reference_memspec_json) -> None:  # type: ignore[no-untyped-def]
    """With an explicit iBeta below IDD2N the precharge energy is negative: named by iBeta."""
    power = reference_memspec_json["memspec"]["mempowerspec"]
    power["iBeta_vdd"] = 0.020
    reference_memspec_json["memspec"]["bankwisespec"] = {"factRho": 0.5}
    message = _error(reference_memspec_json)
    assert "precharge: ibeta_vdd 20 mA < IDD2N 36 mA" in message
