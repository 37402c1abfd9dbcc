"""tRRD_S, tRRD_L and tFAW (issue 30): the spacing core and the controller model's schedule."""

from __future__ import annotations

import numpy as np
import pytest

from hdeem_watch.dram import controller
from hdeem_watch.dram.act_spacing import ActRules, RefreshWindows, recent_activations, space_activations
from hdeem_watch.dram.controller import simulate
from hdeem_watch.dram.ddr5_channel import subchannel_spec
from hdeem_watch.dram.scheduler import SchedulerConfig

from .test_ddr5_stats import ddr5_spec

#: the controller with the activation rules on (off by default: SchedulerConfig.activation_rules)
RULES = SchedulerConfig(activation_rules=True)


def reference(earliest: list[int], rank: list[int], group: list[int], rules: ActRules,
              windows: RefreshWindows | None) -> list[int]:
    """The rules as JEDEC states them, one ACT at a time in order of readiness (ties: input order)."""
    order = sorted(range(len(earliest)), key=lambda i: (rank[i], earliest[i], i))
    issued: dict[int, list[tuple[int, int]]] = {}
    out = [0] * len(earliest)
    for i in order:
        t = earliest[i]
        while True:
            before = issued.get(rank[i], [])
            start = t
            for cycle, g in before:
                t = max(t, cycle + (rules.rrd_l if g == group[i] else rules.rrd_s))
            if len(before) >= 4:
                t = max(t, before[-4][0] + rules.faw)
            if windows is not None:
                k = t // windows.refi
                if k >= windows.first and t - k * windows.refi < windows.length:
                    t = k * windows.refi + windows.length
            if t == start:
                break
        out[i] = t
        issued.setdefault(rank[i], []).append((t, group[i]))
    return out


def violations(cycle: np.ndarray, rank: np.ndarray, group: np.ndarray, rules: ActRules) -> int:
    """ACT pairs closer than tRRD_S/L plus 4-ACT windows shorter than tFAW, per rank."""
    count = 0
    for r in np.unique(rank):
        mine = np.flatnonzero(rank == r)
        order = mine[np.argsort(cycle[mine], kind="stable")]
        c, g = cycle[order], group[order]
        count += int(np.count_nonzero(np.diff(c) < np.where(g[1:] == g[:-1], rules.rrd_l, rules.rrd_s)))
        for grp in np.unique(g):
            count += int(np.count_nonzero(np.diff(c[g == grp]) < rules.rrd_l))
        count += int(np.count_nonzero(c[4:] - c[:-4] < rules.faw))
    return count


@pytest.mark.parametrize("seed", range(40))
def test_spacing_is_the_least_schedule_that_obeys_the_rules(seed: int) -> None:
    """Equal to the rules applied one ACT at a time (so: obeyed, and no ACT later than needed)."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 400))
    earliest = rng.integers(0, int(rng.integers(50, 5000)), n)
    rank = rng.integers(0, 2, n)
    group = rank * 8 + rng.integers(0, 8, n)
    rrd_s = int(rng.integers(0, 10))
    rules = ActRules(rrd_s=rrd_s, rrd_l=rrd_s + int(rng.integers(0, 8)), faw=int(rng.integers(0, 120)))
    windows = RefreshWindows(refi=700, length=int(rng.integers(1, 200)), first=1) if seed % 2 else None
    spaced = space_activations(earliest, rank, group, rules, windows)
    assert spaced.tolist() == reference(earliest.tolist(), rank.tolist(), group.tolist(), rules, windows)
    assert violations(spaced, rank, group, rules) == 0
    assert bool((spaced >= earliest).all())


def test_recent_activations_keep_what_the_rules_look_back_at() -> None:
    """The last four ACTs of each rank and the last of each bank group."""
    cycle = np.array([0, 10, 20, 30, 40, 50, 5, 15])
    rank = np.array([0, 0, 0, 0, 0, 0, 1, 1])
    group = np.array([0, 1, 0, 1, 2, 3, 8, 8])
    recent = recent_activations(cycle, rank, group)
    assert sorted(zip(recent.rank.tolist(), recent.cycle.tolist())) == [
        (0, 20), (0, 30), (0, 40), (0, 50), (1, 5), (1, 15)]


def activation_bound(n: int = 60_000, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Random lines: nearly every request opens a row."""
    rng = np.random.default_rng(seed)
    addresses = (rng.integers(0, 1 << 33, n).astype(np.uint64) >> np.uint64(6)) << np.uint64(6)
    return addresses, rng.random(n) < 0.3


def schedule_violations(faw: int, *, refi: int = 10**9, **timings: int) -> tuple[int, int, float]:
    """(violations, cycles, ACTs) of the activation-bound stream on a DDR5 sub-channel."""
    spec = subchannel_spec(ddr5_spec(FAW_slr=faw, REFI1=refi, **timings))
    result = simulate(spec, *activation_bound(), keep_commands=True, scheduler=RULES)
    commands = result.commands
    assert commands is not None
    groups = commands.act_rank * spec.nbr_of_bankgroups + commands.act_bank // (spec.nbr_of_banks // spec.nbr_of_bankgroups)
    rules = ActRules(int(spec.timings["RRD_S"]), int(spec.timings["RRD_L"]), faw)
    return violations(commands.act_cycle, commands.act_rank, groups, rules), result.cycles, result.stats.total("act")


def test_no_four_activations_within_tfaw_in_the_schedule() -> None:
    """With no refresh in the window, every ACT of the produced schedule obeys tRRD_S/L and tFAW
    (the model before issue 30 broke them: :func:`test_unspaced_schedule_breaks_the_rules`)."""
    spaced, _, _ = schedule_violations(32)
    assert spaced == 0
    big, _, _ = schedule_violations(160)
    assert big == 0


def test_unspaced_schedule_breaks_the_rules() -> None:
    """The same stream with the rules switched off has ACTs closer than the DDR5-4800 rules allow."""
    spec = subchannel_spec(ddr5_spec(FAW_slr=0, RRD_S_slr=0, RRD_L_slr=0, REFI1=10**9))
    result = simulate(spec, *activation_bound(), keep_commands=True, scheduler=RULES)
    commands = result.commands
    assert commands is not None
    groups = commands.act_rank * 8 + commands.act_bank // 4
    assert violations(commands.act_cycle, commands.act_rank, groups, ActRules(8, 12, 32)) > 100


def test_the_rules_are_off_by_default() -> None:
    """Off by default (their cost: SchedulerConfig.activation_rules): the default schedule is the
    one with the rules zeroed, which breaks them on an activation-bound stream."""
    spec = subchannel_spec(ddr5_spec(REFI1=10**9))
    default = simulate(spec, *activation_bound(), keep_commands=True).commands
    zeroed = simulate(subchannel_spec(ddr5_spec(FAW_slr=0, RRD_S_slr=0, RRD_L_slr=0, REFI1=10**9)),
                      *activation_bound(), keep_commands=True).commands
    assert default is not None and zeroed is not None
    assert np.array_equal(default.act_cycle, zeroed.act_cycle)
    groups = default.act_rank * 8 + default.act_bank // 4
    assert violations(default.act_cycle, default.act_rank, groups, ActRules(8, 12, 32)) > 100


def test_large_tfaw_slows_an_activation_bound_stream() -> None:
    """A large tFAW caps the activation rate at four per window: the stream takes longer, with
    fewer ACTs per cycle, and never more than four per tFAW."""
    _, cycles_32, acts_32 = schedule_violations(32)
    _, cycles_200, acts_200 = schedule_violations(200)
    assert cycles_200 > 1.5 * cycles_32
    assert acts_200 / cycles_200 < acts_32 / cycles_32
    assert acts_200 / cycles_200 <= 4 / 200 * 1.001


def test_rules_hold_across_chunks(monkeypatch: pytest.MonkeyPatch) -> None:
    """Chunk boundaries (the model serves long streams in chunks) keep the rules: each chunk sees
    the last ACTs of the one before."""
    monkeypatch.setattr(controller, "CHUNK_REQUESTS", 4096)
    count, _, _ = schedule_violations(400, RP=8, RCD=8)
    assert count == 0


def test_refresh_keeps_the_counts() -> None:
    """With refresh, reads and writes are still the requests'; only the re-activations after a
    refresh are not spaced, so the rules break far less often than without them."""
    addresses, writes = activation_bound()
    counted = []
    for rules in ({}, {"FAW_slr": 0, "RRD_S_slr": 0, "RRD_L_slr": 0}):
        result = simulate(subchannel_spec(ddr5_spec(**rules)), addresses, writes, keep_commands=True, scheduler=RULES)
        assert result.reads + result.writes == result.requests > 0.4 * addresses.size  # sub-channel 0's half
        assert result.stats.total("rd") + result.stats.total("rda") == result.reads
        commands = result.commands
        assert commands is not None
        groups = commands.act_rank * 8 + commands.act_bank // 4
        counted.append(violations(commands.act_cycle, commands.act_rank, groups, ActRules(8, 12, 32)))
    assert counted[0] < 0.25 * counted[1]
