"""perf energy-ram: the perf_event_open plumbing for real (a software event of this process), the power
PMU from a fixture sysfs tree (layout of arch/x86/events/rapl.c's sysfs attributes: type, cpumask,
events/energy-ram{,.scale,.unit}, format/event) with a fake counter layer."""

from __future__ import annotations

import errno
import os
import shutil
import time
from pathlib import Path

import pytest

from hdeem_watch.perf_event import (
    PERF_COUNT_SW_TASK_CLOCK,
    PERF_TYPE_SOFTWARE,
    PerfEvent,
    PerfEventError,
    paranoid_level,
)
from hdeem_watch.sources.base import SourceUnavailable
from hdeem_watch.sources.perf_energy import event_config, perf_counters
from hdeem_watch.sources.rapl import RaplSource

FIXTURES = Path(__file__).resolve().parent / "fixtures"
SCALE = 2.3283064365386962890625e-10


@pytest.fixture
def power_pmu(powercap_trees: Path) -> Path:
    return powercap_trees / "perf_power" / "bus" / "event_source" / "devices" / "power"


@pytest.fixture
def cpu_dir(powercap_trees: Path) -> Path:
    return powercap_trees / "perf_power" / "devices" / "system" / "cpu"


class FakeEvent:
    """A counting event the test advances: counts in units of ``scale`` J."""

    def __init__(self, log: list, type_: int, config: int, cpu: int) -> None:
        self.count = 1000 * (cpu + 1)
        self.closed = False
        log.append((type_, config, cpu, self))

    def read(self) -> int:
        return self.count

    def close(self) -> None:
        self.closed = True


@pytest.mark.slow
def test_software_event_counts_for_real():
    """perf_event_open of this process's task clock (allowed at perf_event_paranoid <= 2 with
    exclude_kernel): the count grows with CPU time spent, and close releases the descriptor."""
    level = paranoid_level()
    privileged = os.geteuid() == 0      # CAP_PERFMON / CAP_SYS_ADMIN: any paranoid level
    assert level is not None and (level <= 2 or privileged), f"perf_event_paranoid = {level}: the test needs <= 2"
    event = PerfEvent.open(PERF_TYPE_SOFTWARE, PERF_COUNT_SW_TASK_CLOCK, pid=0, cpu=-1, exclude_kernel=True,
                           exclude_hv=True)
    try:
        before = event.read()
        deadline = time.process_time() + 0.05
        while time.process_time() < deadline:
            pass
        after = event.read()
        assert after - before >= 30_000_000          # ns of task clock: at least 30 of the 50 ms spun
    finally:
        event.close()
    assert event.fd == -1


@pytest.mark.slow
def test_refused_event_raises_with_errno():
    """A config no PMU knows fails with an OSError carrying errno (not a crash, not a zero count)."""
    with pytest.raises(PerfEventError) as info:
        PerfEvent.open(PERF_TYPE_SOFTWARE, 0xFFFF, pid=0, cpu=-1, exclude_kernel=True)
    assert info.value.errno in (errno.EINVAL, errno.ENOENT, errno.EOPNOTSUPP)


def test_config_word_from_the_format_files(power_pmu):
    """'event=0x03' with format/event 'config:0-7' is config 3."""
    assert event_config(power_pmu, "event=0x03\n") == 3


def test_one_counter_per_socket_from_the_cpumask(power_pmu, cpu_dir):
    """cpumask 0,24 → events on CPU 0 (package 0) and 24 (package 1), the PMU's type and config, in
    Joules × the sysfs scale; closing closes every event."""
    log: list = []
    counters, close = perf_counters(power_pmu, cpu_dir, opener=lambda t, c, cpu: FakeEvent(log, t, c, cpu))
    assert [c.channel for c in counters] == ["DRAM0", "DRAM1"]
    assert [(t, c, cpu) for t, c, cpu, _ in log] == [(20, 3, 0), (20, 3, 24)]
    assert counters[1].joules_per_unit == SCALE and counters[1].modulus is None
    assert counters[1].read_raw() == 25_000
    close()
    assert all(event.closed for *_, event in log)


def test_rapl_auto_falls_back_to_perf_when_powercap_is_closed(power_pmu, cpu_dir, powercap_trees, tmp_path):
    """method='auto': energy_uj denied (CVE-2020-8694) → the power PMU; ΔE/Δt from the scaled counts."""
    log: list = []
    tree = tmp_path / "pc"
    shutil.copytree(powercap_trees / "powercap_haswell_ep", tree)

    def denied(path: Path) -> str:
        if path.name == "energy_uj":
            raise PermissionError(13, "Permission denied", str(path))
        return path.read_text()

    now = [0]
    src = RaplSource(root=tree, method="auto", read_text=denied, clock=lambda: now[0],
                     perf_options={"sysfs": power_pmu, "cpu_dir": cpu_dir,
                                   "opener": lambda t, c, cpu: FakeEvent(log, t, c, cpu)})
    src.open()
    assert src.used_method == "perf" and [c.name for c in src.channels()] == ["DRAM0", "DRAM1"]
    log[0][3].count += round(3.0 / SCALE)            # 3 J on socket 0 in 0.5 s
    now[0] += 500_000_000
    batch = src.poll()
    assert batch.samples["DRAM0"][1][0] == pytest.approx(6.0, rel=1e-9)
    assert batch.status["DRAM1"] == "stale"
    src.close()
    assert all(event.closed for *_, event in log)


def test_perf_refused_names_paranoid_and_capability(power_pmu, cpu_dir):
    """EACCES from perf_event_open → unavailable, naming perf_event_paranoid and CAP_PERFMON."""
    def refuse(t: int, c: int, cpu: int) -> FakeEvent:
        raise PerfEventError(errno.EACCES, "Permission denied")

    with pytest.raises(SourceUnavailable, match=r"perf_event_paranoid = 2.*CAP_PERFMON"):
        perf_counters(power_pmu, cpu_dir, opener=refuse, paranoid=lambda: 2)


def test_pmu_without_energy_ram_says_what_the_cpu_offers(power_pmu, cpu_dir, tmp_path):
    """An AMD power PMU (energy-pkg only): the reason is the AMD one, not a permission hint."""
    pmu = tmp_path / "power"
    shutil.copytree(power_pmu, pmu)
    for name in ("energy-ram", "energy-ram.scale", "energy-ram.unit"):
        (pmu / "events" / name).unlink()
    with pytest.raises(SourceUnavailable, match="AMD CPU"):
        perf_counters(pmu, cpu_dir, cpuinfo=FIXTURES / "cpuinfo" / "amd_epyc_7763.txt")
    with pytest.raises(SourceUnavailable, match="no power PMU"):
        perf_counters(tmp_path / "none", cpu_dir)
