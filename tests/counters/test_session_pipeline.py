"""The whole counting path on a fixture Haswell-EP host, with the fake reader standing in for the syscall.

plan (fixture sysfs) → open every event per channel → two multiplexed reads → window deltas → roles
→ CommandStats, compared with the hidden truth the fake's counts came from.
"""

from __future__ import annotations

import errno
from pathlib import Path

import pytest

from hdeem_watch.counters.command_mapping import channel_stats
from hdeem_watch.counters.host_plan import plan_host
from hdeem_watch.counters.permissions import check_access
from hdeem_watch.counters.reader import FakeCounterReader
from hdeem_watch.counters.session import CounterSession
from hdeem_watch.dram.kernels import kernel_stats
from hdeem_watch.dram.memspec import preset
from hdeem_watch.sim.imc_events import imc_event_counts

# One worker runs the module, so its module-scoped fixture is built once, not once per worker.
pytestmark = pytest.mark.xdist_group("counters-session_pipeline")

FIXTURES = Path(__file__).resolve().parent / "fixtures"
SPEC = preset("samsung-m393a1g43db0-cpb")
WINDOW_NS = 1_000_000_000


class Clock:
    def __init__(self) -> None:
        self.t = 5_000_000

    def __call__(self) -> int:
        return self.t


@pytest.fixture(scope="module")
def plan(pmu_trees):
    cpuinfo = (FIXTURES / "cpuinfo/haswell_ep").read_text()
    return plan_host(pmu_trees / "sysfs_haswell_ep", cpuinfo_text=cpuinfo,
                     access=check_access(paranoid=2, capabilities=1 << 38), ranks=2)


def test_multiplexed_window_recovers_each_channels_truth(plan):
    """Socket 0 runs a triad, socket 1 idles; 14 events on 4 counters (share 4/14) still give each truth."""
    busy = kernel_stats(SPEC, "triad", 1_000_000, 12, repeat=1, channels=4).stats
    idle = kernel_stats(SPEC, "triad", 10_000, 1, repeat=1, channels=4).stats
    by_cpu = {0: busy, 12: idle}
    configs = {(c.pmu_type, c.cpu): imc_event_counts(by_cpu[c.cpu], plan.table) for c in plan.channels}
    names = {e.config: e.name for e in plan.events}

    def truth(pmu_type: int, config: int, cpu: int, elapsed_ns: int) -> int:
        return configs[(pmu_type, cpu)][names[config]] * elapsed_ns // WINDOW_NS

    clock = Clock()
    distinct = len({e.name for e in plan.events})
    reader = FakeCounterReader(truth, clock=clock, running_share=4 / distinct,
                               known_types=frozenset(c.pmu_type for c in plan.channels))
    session = CounterSession(reader, plan.channels, plan.events).open()
    assert reader.open_handles == len(plan.channels) * distinct == 8 * 14
    clock.t += WINDOW_NS // 4
    before = session.read()
    clock.t += WINDOW_NS // 2
    deltas = session.role_deltas(before, session.read())
    session.close()
    assert reader.open_handles == 0
    for channel in plan.channels:
        hidden = by_cpu[channel.cpu]
        cycles = hidden.ranks[0].cycles_total / 2
        result = channel_stats(deltas[channel.name], ranks=2, window_cycles=cycles,
                               open_cycles_per_act=SPEC.timings["RC"], refresh_complete=plan.table.refresh_complete,
                               trefi_cycles=SPEC.timings["REFI"])
        assert result.stats is not None, result.status
        for field in ("act", "rd", "wr"):
            assert result.stats.total(field) == pytest.approx(hidden.total(field) / 2, rel=2e-3, abs=4), field


def test_permission_denied_closes_nothing_left_open(plan):
    """An EACCES from the syscall propagates with its errno and leaves no event open."""
    reader = FakeCounterReader(lambda *a: 0, denied=True)
    with pytest.raises(OSError) as error:
        CounterSession(reader, plan.channels, plan.events).open()
    assert error.value.errno == errno.EACCES
    assert reader.open_handles == 0


def test_failure_midway_closes_what_was_opened(plan):
    """If socket 1's PMU type is unknown to the kernel, socket 0's already-open events are closed again."""
    reader = FakeCounterReader(lambda *a: 0, known_types=frozenset({plan.channels[0].pmu_type}))
    session = CounterSession(reader, plan.channels, plan.events)
    with pytest.raises(OSError):
        session.open()
    assert reader.open_handles == 0 and not session.open_events
