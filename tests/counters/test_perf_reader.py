"""The real ``perf_event_open`` reader, and the daemon's perf counter source on fixture uncore hosts.

The syscall plumbing runs for real with a software event (this VM has no uncore PMU:
``/sys/bus/event_source/devices`` has only breakpoint, msr, software, tracepoint, uprobe); the
uncore path runs on the fixture sysfs trees of a Haswell-EP and an Ice Lake-SP host with the fake
read layer (:class:`~hdeem_watch.counters.reader.FakeCounterReader`, which mimics perf_event_open(2):
counts accrue while the event runs, multiplexed events run a share of the enabled time).
"""

from __future__ import annotations

import errno
from pathlib import Path

import pytest

from hdeem_watch.calibrate.counter_model import counter_groups
from hdeem_watch.counters.host_plan import PlannedChannel, PlannedEvent, plan_host
from hdeem_watch.counters.perf_counters import PerfCounters
from hdeem_watch.counters.perf_reader import PerfCounterReader
from hdeem_watch.counters.permissions import check_access
from hdeem_watch.counters.reader import FakeCounterReader
from hdeem_watch.counters.session import CounterSession
from hdeem_watch.counters.source import window_counts
from hdeem_watch.dram.kernels import kernel_stats
from hdeem_watch.dram.memspec import preset
from hdeem_watch.errors import InputError
from hdeem_watch.perf_event import PERF_COUNT_SW_TASK_CLOCK, PERF_TYPE_SOFTWARE
from hdeem_watch.sim.imc_events import imc_event_counts

FIXTURES = Path(__file__).resolve().parent / "fixtures"
SPEC = preset("samsung-m393a1g43db0-cpb")
SECOND = 1_000_000_000


def busy_loop() -> int:
    return sum(i * i for i in range(200_000))


@pytest.mark.slow
def test_the_real_syscall_reads_count_and_times() -> None:
    """This process's task clock through the real syscall: the count and both times grow; without
    multiplexing running == enabled; a closed handle is EBADF."""
    reader = PerfCounterReader(pid=0, exclude_kernel=True)
    handle = reader.open(PERF_TYPE_SOFTWARE, PERF_COUNT_SW_TASK_CLOCK, cpu=-1)
    first = reader.read(handle)
    busy_loop()
    second = reader.read(handle)
    assert second.value > first.value > 0
    assert second.time_enabled_ns > first.time_enabled_ns and second.time_running_ns == second.time_enabled_ns
    assert reader.open_handles == 1
    reader.close(handle)
    assert reader.open_handles == 0
    for call in (reader.read, reader.close):
        with pytest.raises(OSError) as caught:
            call(handle)
        assert caught.value.errno == errno.EBADF


@pytest.mark.slow
def test_a_session_over_the_real_syscall_gives_window_deltas() -> None:
    """The counting session (open per channel, snapshots, role deltas) on real readings of a software event."""
    channel = PlannedChannel(name="S0.sw", socket=0, box=0, pmu="software", pmu_type=PERF_TYPE_SOFTWARE, cpu=-1)
    event = PlannedEvent(role="dclk", name="task-clock", event=PERF_COUNT_SW_TASK_CLOCK, umask=0,
                         config=PERF_COUNT_SW_TASK_CLOCK, experimental=False)
    reader = PerfCounterReader(pid=0, exclude_kernel=True)
    session = CounterSession(reader, [channel], [event]).open()
    before = session.read()
    busy_loop()
    deltas = session.role_deltas(before, session.read())
    session.close()
    assert deltas["S0.sw"]["dclk"] > 0 and reader.open_handles == 0


@pytest.mark.slow
def test_an_unknown_pmu_type_is_the_kernels_error() -> None:
    """A PMU type the kernel does not have: the syscall's errno, not a made-up count."""
    with pytest.raises(OSError) as caught:
        PerfCounterReader().open(0x7FFF_FFF0, 0x0304, cpu=0)
    assert caught.value.errno in (errno.ENOENT, errno.EINVAL, errno.ENODEV, errno.EACCES, errno.EPERM)


@pytest.mark.parametrize("host", ["haswell_ep", "ice_lake_sp"])
def test_the_perf_counter_source_on_fixture_hosts_recovers_the_truth(pmu_trees: Path, host: str) -> None:
    """Every planned event on every channel, multiplexed 4 of N: two reads a second apart give each
    channel's hidden triad counts (scaled back), and the model's statistics from them."""
    cpuinfo = (FIXTURES / "cpuinfo" / host).read_text()
    plan = plan_host(pmu_trees / f"sysfs_{host}", cpuinfo_text=cpuinfo,
                     access=check_access(paranoid=2, capabilities=1 << 38), ranks=2)
    assert plan.usable, plan.reasons
    truth_stats = kernel_stats(SPEC, "triad", 1_000_000, 12, repeat=1, channels=4).stats
    window_cycles = truth_stats.ranks[0].cycles_total
    per_second = imc_event_counts(truth_stats, plan.table)
    names = {e.config: e.name for e in plan.events}
    now = [7 * SECOND]

    def truth(pmu_type: int, config: int, cpu: int, elapsed_ns: int) -> int:
        return per_second[names[config]] * elapsed_ns // SECOND

    distinct = len({e.name for e in plan.events})
    reader = FakeCounterReader(truth, clock=lambda: now[0], running_share=4 / distinct)
    counters = PerfCounters(plan, reader, sample_time=lambda t: t + 10**18, clock=lambda: now[0], ranks=2)
    start = counters.read()
    now[0] += SECOND
    end = counters.read()
    assert end.t_ns - start.t_ns == SECOND
    counts = window_counts(start, end)
    assert set(counts) == {c.name for c in plan.channels}
    one = counts[plan.channels[0].name]
    assert one["cas_rd"] == pytest.approx(truth_stats.total("rd") + truth_stats.total("rda"), rel=1e-4)  # integer counts
    groups, _notes = counter_groups(SPEC, {"window_s": window_cycles * SPEC.tck_s, "ranks": 2,
                                           "refresh_complete": plan.table.refresh_complete, "channels": counts})
    assert len(groups) == len(plan.channels)
    # each ACT event runs 4 of ``distinct`` slots and its integer count is scaled back by distinct/4:
    # off by less than that per event
    scaling_error = len(plan.table.events_of("act")) * distinct / 4
    assert groups[0][0].total("act") == pytest.approx(truth_stats.total("act"), abs=scaling_error)
    counters.close()
    assert reader.open_handles == 0


def test_refused_opens_are_explained_and_nothing_stays_open(pmu_trees: Path) -> None:
    """EACCES names the paranoid level and the fix; a missing PMU says so; either way no event stays open."""
    cpuinfo = (FIXTURES / "cpuinfo" / "haswell_ep").read_text()
    plan = plan_host(pmu_trees / "sysfs_haswell_ep", cpuinfo_text=cpuinfo,
                     access=check_access(paranoid=2, capabilities=0), ranks=2)
    denied = FakeCounterReader(lambda *a: 0, denied=True)
    with pytest.raises(InputError, match=r"not allowed.*perf_event_paranoid"):
        PerfCounters(plan, denied, sample_time=lambda t: t, clock=lambda: 0, ranks=2)
    missing = FakeCounterReader(lambda *a: 0, known_types=frozenset())
    with pytest.raises(InputError, match="does not exist on this host"):
        PerfCounters(plan, missing, sample_time=lambda t: t, clock=lambda: 0, ranks=2)
    assert denied.open_handles == missing.open_handles == 0
