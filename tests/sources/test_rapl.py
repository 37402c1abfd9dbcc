"""The RAPL DRAM source against checked-in powercap fixture trees."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from hdeem_watch.sources.base import RAPL_DRAM_COVERS, SourceUnavailable
from hdeem_watch.sources.rapl import RaplSource, probe, wrap_delta_uj, wrap_modulus_uj
from hdeem_watch.sources.registry import available_sources, make_source

RANGE = 262143328850


@pytest.fixture
def tree(powercap_trees, tmp_path) -> Path:
    root = tmp_path / "powercap"
    shutil.copytree(powercap_trees / "powercap_haswell_ep", root)
    return root


def dram(root: Path, socket: int) -> Path:
    return root / f"intel-rapl:{socket}" / f"intel-rapl:{socket}:0" / "energy_uj"


def bump(path: Path, delta_uj: int, max_range: int = RANGE) -> None:
    """Add energy as the kernel shows it: the register's period is 2^32 units = max_range + one unit."""
    value = int(path.read_text())
    path.write_text(f"{int((value + delta_uj) % (max_range * 2**32 / (2**32 - 1)))}\n")


def test_dram_zones_per_socket(tree):
    """Zones named 'dram' become DRAM0/DRAM1 (per socket, covering two HDEEM DIMM pairs each)."""
    src = RaplSource(root=tree)
    src.open()
    assert [c.name for c in src.channels()] == ["DRAM0", "DRAM1"]
    assert all(c.kind == "dram" for c in src.channels())
    assert set(RAPL_DRAM_COVERS) == {"DRAM0", "DRAM1"}
    assert probe(tree) is None


def test_power_is_delta_e_over_delta_t_across_a_wrap(tree, fake_clock):
    """ΔE/Δt per poll; socket 0's counter wraps between polls and the delta is taken modulo the
    register's period (max_energy_range_uj + one unit)."""
    clock = fake_clock(1_000_000_000)
    src = RaplSource(root=tree, clock=clock)
    src.open()
    bump(dram(tree, 0), 3_000_000)          # crosses max_energy_range_uj
    bump(dram(tree, 1), 1_500_000)
    clock.t += 500_000_000
    batch = src.poll()
    assert int(dram(tree, 0).read_text()) < 3_000_000          # it really wrapped
    assert batch.samples["DRAM0"][1][0] == pytest.approx(6.0)  # 3 J in 0.5 s
    assert batch.samples["DRAM1"][1][0] == pytest.approx(3.0)
    assert batch.energy_j == {"DRAM0": pytest.approx(3.0), "DRAM1": pytest.approx(1.5)}
    assert wrap_delta_uj(RANGE, 0, wrap_modulus_uj(RANGE)) == pytest.approx(61.035, abs=1e-3)


@pytest.mark.parametrize(("unit_pj", "what"), [(15300, "Haswell-EP DRAM domain, 15.3 uJ"),
                                               (61035, "2^-14 J, the package unit of these trees")])
def test_wrap_modulus_is_the_registers_period(unit_pj, what):
    """drivers/powercap/intel_rapl_common.c: energy_uj = raw * unit // 1000 (rapl_unit_xlate, unit in the
    driver's 1e-9 uJ steps) of the 32-bit MSR (ENERGY_STATUS_MASK), max_energy_range_uj the same of
    0xffffffff. A wrap from raw 2^32 - 7 to 9 is 16 units; the delta matches within 1 uJ (truncation),
    where 'max_energy_range_uj + 1' misses one unit minus 1 uJ (14.3 uJ on the DRAM unit)."""
    def energy_uj(raw: int) -> int:
        return raw * unit_pj // 1000

    max_range = energy_uj(2**32 - 1)
    old, new = energy_uj(2**32 - 7), energy_uj(9)
    true_uj = 16 * unit_pj / 1000
    assert abs(wrap_delta_uj(old, new, wrap_modulus_uj(max_range)) - true_uj) < 1.0, what
    assert (new - old) % (max_range + 1) == pytest.approx(true_uj - (unit_pj / 1000 - 1), abs=1.0)


def test_unmoved_counter_gives_no_sample_not_zero(tree, fake_clock):
    """A counter that did not move since the last poll yields no sample (never a 0 W sample)."""
    clock = fake_clock(1_000_000_000)
    src = RaplSource(root=tree, clock=clock, interval_s=0.0)
    src.open()
    clock.t += 1_000_000
    batch = src.poll()
    assert len(batch.samples["DRAM0"][1]) == 0 and batch.status["DRAM0"] == "stale"
    bump(dram(tree, 0), 2_000)
    clock.t += 1_000_000
    batch = src.poll()
    assert batch.samples["DRAM0"][1][0] == pytest.approx(1.0)   # 2 mJ over both intervals (2 ms)


def test_uncorrectable_jump_is_dropped(tree, fake_clock):
    """A delta implying an impossible power (several wraps or a reset) is dropped, not published."""
    clock = fake_clock(1_000_000_000)
    src = RaplSource(root=tree, clock=clock, max_power_w=200.0)
    src.open()
    dram(tree, 1).write_text("4000000\n")   # went backwards by 1 J: looks like a wrap of ~262 kJ
    clock.t += 100_000_000
    batch = src.poll()
    assert len(batch.samples["DRAM1"][1]) == 0 and batch.status["DRAM1"].startswith("error")
    assert src.dropped["DRAM1"] == 1 and batch.energy_j["DRAM1"] == 0.0
    bump(dram(tree, 1), 100_000)
    clock.t += 100_000_000
    assert src.poll().samples["DRAM1"][1][0] == pytest.approx(1.0)   # re-baselined after the drop


def test_permission_denied_names_the_fix(tree):
    """EACCES on energy_uj → SourceUnavailable saying to run as the privileged collector."""
    os.chmod(dram(tree, 0), 0)
    if os.access(dram(tree, 0), os.R_OK):     # running as root: chmod cannot deny, inject EACCES instead
        def read_text(path: Path) -> str:
            if path.name == "energy_uj":
                raise PermissionError(13, "Permission denied", str(path))
            return path.read_text()
    else:
        def read_text(path: Path) -> str:
            return path.read_text()
    with pytest.raises(SourceUnavailable, match="privileged collector") as info:
        RaplSource(root=tree, read_text=read_text).open()
    assert "root-only" in info.value.reason


def test_no_dram_zone_and_missing_root(powercap_trees, tmp_path):
    """A client CPU (no 'dram' zone) and a missing powercap tree are unavailable with the reason."""
    with pytest.raises(SourceUnavailable, match="no DRAM zone"):
        make_source("rapl", root=powercap_trees / "powercap_laptop").open()
    reason = available_sources(rapl_root=str(tmp_path / "nope"))["rapl"]
    assert reason and "does not exist" in reason


def test_counters_read_at_most_every_interval(tree, fake_clock):
    """Polled at 40 Hz with interval_s = 0.1, the zones are read ten times a second (nominal rate)."""
    clock = fake_clock(1_000_000_000)
    src = RaplSource(root=tree, clock=clock, interval_s=0.1)
    src.open()
    n = 0
    for _ in range(40):
        clock.t += 25_000_000
        bump(dram(tree, 1), 25_000)
        n += len(src.poll().samples["DRAM1"][0])
    assert n == 10 and src.channels()[1].rate_hz == 10.0
