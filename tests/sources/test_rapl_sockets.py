"""RAPL zones map to sockets by their package zone's name, in kernel-layout fixture trees.

Trees (powercap_trees.py, built per session) are laid out as sysfs presents powercap: zones numbered in
registration order in hex (drivers/powercap/powercap_sys.c, powercap_register_zone), package zones
named package-X or package-X-die-Y (drivers/powercap/intel_rapl_common.c, rapl_add_package), and
class/powercap holding a symlink per zone.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from hdeem_watch.config import load_settings
from hdeem_watch.daemon.book.channels import ChannelAccount
from hdeem_watch.sources.rapl import RaplSource
from hdeem_watch.sources.rapl_zones import find_dram_zones
from hdeem_watch.sources.registry import make_source

FIXTURES = Path(__file__).resolve().parent / "fixtures"
DEVICES = Path("devices/virtual/powercap/intel-rapl")



def copy(trees: Path, tmp_path: Path, name: str) -> Path:
    shutil.copytree(trees / name, tmp_path / name, symlinks=True)
    return tmp_path / name


def bump(tree: Path, zone: str, delta_uj: int) -> None:
    path = next((tree / DEVICES).glob(f"*/{zone}")) / "energy_uj"
    path.write_text(f"{int(path.read_text()) + delta_uj}\n")


def powers(tree: Path, bumps: dict[str, int], clock) -> dict[str, float]:  # clock: a fake_clock()
    """Open the source on class/powercap, bump zones (µJ) over 1 s, return the published powers."""
    src = RaplSource(root=tree / "class" / "powercap", clock=clock)
    src.open()
    for zone, delta in bumps.items():
        bump(tree, zone, delta)
    clock.t += 1_000_000_000
    batch = src.poll()
    return {ch: float(p[0]) for ch, (_, p) in batch.samples.items() if len(p)}


def test_registration_order_is_not_socket_order(powercap_trees, tmp_path, fake_clock):
    """intel-rapl:0 is package-1 here: its DRAM zone is DRAM1, not DRAM0."""
    tree = copy(powercap_trees, tmp_path, "powercap_2s_swapped")
    zones = find_dram_zones(tree / "class" / "powercap")
    assert [(z.channel, z.path.name) for z in zones] == [("DRAM0", "intel-rapl:1:0"), ("DRAM1", "intel-rapl:0:0")]
    assert powers(tree, {"intel-rapl:0:0": 3_000_000, "intel-rapl:1:0": 1_000_000}, fake_clock(1_000_000_000)) == {
        "DRAM0": pytest.approx(1.0), "DRAM1": pytest.approx(3.0)}


def test_four_sockets_registered_out_of_order(powercap_trees, tmp_path, fake_clock):
    """4 sockets registered 2, 0, 3, 1 (and a psys zone): DRAM0..DRAM3 each read their own socket."""
    tree = copy(powercap_trees, tmp_path, "powercap_4s")
    zones = find_dram_zones(tree / "class" / "powercap")
    assert [z.channel for z in zones] == ["DRAM0", "DRAM1", "DRAM2", "DRAM3"]
    assert [z.path.name for z in zones] == ["intel-rapl:1:0", "intel-rapl:3:0", "intel-rapl:0:0", "intel-rapl:2:0"]
    got = powers(tree, {f"intel-rapl:{i}:0": (i + 1) * 1_000_000 for i in range(4)}, fake_clock(1_000_000_000))
    assert got == {"DRAM2": pytest.approx(1.0), "DRAM0": pytest.approx(2.0), "DRAM3": pytest.approx(3.0),
                   "DRAM1": pytest.approx(4.0)}


def test_multi_die_packages_name_socket_and_die(powercap_trees, tmp_path, fake_clock):
    """package-X-die-Y zones give DRAM<X>_DIE<Y>; a die without a DRAM zone gives no channel."""
    tree = copy(powercap_trees, tmp_path, "powercap_multidie")
    zones = find_dram_zones(tree / "class" / "powercap")
    assert [(z.channel, z.socket, z.die) for z in zones] == [("DRAM0_DIE0", 0, 0), ("DRAM1_DIE0", 1, 0),
                                                              ("DRAM1_DIE1", 1, 1)]
    assert powers(tree, {"intel-rapl:2:0": 2_000_000}, fake_clock(1_000_000_000))["DRAM0_DIE0"] == pytest.approx(2.0)


def test_nested_tree_without_symlinks_maps_the_same(powercap_trees, tmp_path):
    """The real device directories (nested, no class/ symlinks) give the same mapping."""
    tree = copy(powercap_trees, tmp_path, "powercap_4s")
    zones = find_dram_zones(tree / DEVICES)
    assert (zones[0].channel, zones[0].path.name) == ("DRAM0", "intel-rapl:1:0")


def test_health_recovers_when_every_channel_reads_again(powercap_trees, tmp_path, fake_clock):
    """Issue 22.12: a read error makes health 'error: ...'; once every counter reads again it is 'ok'."""
    tree = copy(powercap_trees, tmp_path, "powercap_2s_swapped")
    failing: set[str] = set()

    def read(path: Path) -> str:
        if path.name == "energy_uj" and path.parent.name in failing:
            raise OSError(5, "Input/output error")
        return path.read_text()

    clock = fake_clock(1_000_000_000)
    src = RaplSource(root=tree / "class" / "powercap", clock=clock, read_text=read)
    src.open()
    failing.add("intel-rapl:0:0")
    clock.t += 200_000_000
    batch = src.poll()
    assert batch.status["DRAM1"].startswith("error") and src.health().startswith("error: DRAM1")
    failing.clear()
    bump(tree, "intel-rapl:0:0", 1000)
    bump(tree, "intel-rapl:1:0", 1000)
    clock.t += 200_000_000
    batch = src.poll()
    assert batch.status == {"DRAM0": "ok", "DRAM1": "ok"} and src.health() == "ok"


def test_idle_polling_reports_no_false_missing_samples(powercap_trees, tmp_path, fake_clock):
    """Issue 22.12: the daemon's idle poll (0.25 s, with jitter) over the rapl source built from the
    settings gives no 'missing' samples (was ~6.4 per second per channel at a nominal 10 Sa/s)."""
    tree = copy(powercap_trees, tmp_path, "powercap_2s_swapped")
    settings = load_settings(env={"HDEEM_WATCH_SOURCE": "rapl", "HDEEM_WATCH_RAPL_ROOT": str(tree / "class/powercap")})
    clock = fake_clock(1_000_000_000)
    wall = fake_clock(1_000_000_000)
    src = make_source("rapl", **settings.source_options(), clock=clock, wall_clock=wall)
    src.open()
    rate = {c.name: c.rate_hz for c in src.channels()}
    accounts = {name: ChannelAccount(name, r, "dram") for name, r in rate.items()}
    rng = np.random.default_rng(3)
    missing = 0
    for _ in range(120):                        # 30 s of idle polling
        step = int(250_000_000 + rng.uniform(-0.02, 0.02) * 1e9)
        clock.t += step
        wall.t += step
        bump(tree, "intel-rapl:0:0", 300_000)
        bump(tree, "intel-rapl:1:0", 200_000)
        batch = src.poll()
        for name, (t, p) in batch.samples.items():
            missing += accounts[name].update(t, p, energy_j=batch.energy_j[name], status=batch.status[name])[1]
    assert sum(a.samples for a in accounts.values()) >= 2 * 110
    assert missing == 0


def test_laptop_tree_says_what_this_cpu_offers(powercap_trees, tmp_path):
    """No DRAM zone: the reason names the CPU's vendor and what to use instead (from /proc/cpuinfo)."""
    with pytest.raises(Exception, match=r"Intel client CPU .*no DRAM energy.*use the hdeem source"):
        RaplSource(root=powercap_trees / "powercap_laptop", cpuinfo=FIXTURES / "cpuinfo" / "intel_core_i7_1165g7.txt").open()
