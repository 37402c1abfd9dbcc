"""Parsing real checkHdeem / hdeem_get_stats printouts from Taurus (reference/taurus)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from hdeem_watch.calibrate.hdeem_printout import parse_printout, read_printout
from hdeem_watch.errors import InputError
from hdeem_watch.sources.base import CHANNELS

TAURUS = Path(__file__).resolve().parents[1] / "data" / "taurus"
FILES = ("6262taurus.txt", "6415.txt", "6485taurus.txt")


@pytest.mark.parametrize("name", FILES)
def test_every_block_has_all_seven_sensors(name):
    """Every block of each capture yields the seven HDEEM channels under their canonical names."""
    p = read_printout(TAURUS / name)
    assert p.blocks
    for block in p.blocks:
        assert list(block.sensors) == list(CHANNELS)
    kinds = [b.kind for b in p.blocks]
    assert kinds.count("instant") == 1 and "stats" in kinds and "stats_total" in kinds
    assert json.loads(json.dumps(p.to_dict()))["blocks"]


@pytest.mark.parametrize("name", FILES)
def test_checkhdeem_energy_is_average_times_samples_over_rate(name):
    """In the checkHdeem tables energy = average × samples / rate (to the printed rounding)."""
    for block in read_printout(TAURUS / name).blocks:
        if block.blade_samples is None:
            continue
        assert 990 < block.blade_rate_hz < 1010 and 97 < block.vr_rate_hz < 103
        for ch, row in block.sensors.items():
            n, rate = (block.blade_samples, block.blade_rate_hz) if ch == "BLADE" else (block.vr_samples,
                                                                                        block.vr_rate_hz)
            expected = row.average_w * n / rate
            assert row.energy_j == pytest.approx(expected, rel=0.02, abs=0.002), (name, block.kind, ch)


def test_6262_lacks_duration_so_rates_are_derived():
    """6262's checkHdeem has no duration/frequency lines: rates are derived (≈1000 and ≈100 Sa/s)."""
    stats = [b for b in read_printout(TAURUS / "6262taurus.txt").of_kind("stats") if b.blade_samples]
    (block,) = stats
    assert block.rates_derived
    assert block.blade_samples == 61 and block.vr_samples == 7
    assert block.blade_rate_hz == pytest.approx(1000, rel=0.005)
    assert block.vr_rate_hz == pytest.approx(100, rel=0.005)
    assert block.duration_s == pytest.approx(0.061, abs=0.001)
    assert block.time_blade == "2021-04-29 07:46:35.759" and block.time_vr == "2021-04-29 07:46:35.730"
    row = block.sensors["DDR_CD"]
    assert (row.max_w, row.min_w, row.average_w, row.energy_j) == (1.25, 0.375, 0.729, 0.051)


def test_6485_printed_rates_and_values():
    """6485's checkHdeem prints duration and real rates; they are taken as printed."""
    (block,) = [b for b in read_printout(TAURUS / "6485taurus.txt").of_kind("stats") if b.blade_samples]
    assert not block.rates_derived
    assert (block.blade_samples, block.vr_samples, block.duration_s) == (1579, 158, 1.578)
    assert block.blade_rate_hz == 1000.000764 and block.vr_rate_hz == 100.063408
    assert block.sensors["DDR_GH"].energy_j == 4.130
    total = next(b for b in read_printout(TAURUS / "6485taurus.txt").of_kind("stats_total") if b.blade_samples)
    assert total.blade_samples == 28409622775 and total.sensors["BLADE"].energy_j == 5658837675.498
    assert total.vr_rate_hz == pytest.approx(100.0, rel=0.001)


def test_get_stats_lines_and_total_min_max_unknown():
    """Benchmark lines give average/max/min; with get_stats_total min/max (printed 0) are unknown (NaN)."""
    p = read_printout(TAURUS / "6262taurus.txt")
    first = p.blocks[0]
    assert first.kind == "stats" and first.real_s == pytest.approx(2.479)
    assert first.sensors["BLADE"].average_w == 103.032 and first.sensors["BLADE"].max_w == 107.625
    assert first.sensors["DDR_GH"].min_w == 0.0          # a real 0 of get_stats stays 0
    total = p.blocks[1]
    assert total.kind == "stats_total"
    assert math.isnan(total.sensors["CPU0"].max_w) and total.sensors["CPU0"].average_w == 68.928
    instant = p.of_kind("instant")[0]
    assert instant.sensors["BLADE"].instant_w == 86.125


def test_malformed_row_names_the_line():
    """A table row with the wrong number of values is an InputError naming file and line."""
    text = "==== HDEEM statistics ====\n  Max (W)  Min (W)  Average (W)  Energy (J)\nBLADE 1.0 2.0 x\n"
    with pytest.raises(InputError, match=r"p\.txt:3"):
        parse_printout(text, where="p.txt")
    with pytest.raises(InputError, match="no HDEEM statistics"):
        parse_printout("hello\n", where="p.txt")


def test_dram_energy_for_import():
    """A checkHdeem block gives the DIMM pairs' energy (sum of the four printed energies) for import."""
    (block,) = [b for b in read_printout(TAURUS / "6485taurus.txt").of_kind("stats") if b.blade_samples]
    assert block.dram_energy_j() == pytest.approx(1.996 + 0.802 + 1.580 + 4.130)
    first = read_printout(TAURUS / "6485taurus.txt").blocks[1]      # get_stats lines: no duration
    assert math.isnan(first.dram_energy_j())
