"""The vectorised trace state machine against DRAMPower: reference traces and a literal oracle.

The oracle below is a plain, command-by-command transcription of DRAMPower v6.2's ``DDR4Core``
(interval counters, implicit-command queue); random legal traces (auto-precharge, PREA, refresh,
deferred power-down entry/exit, self-refresh, several ranks) must give identical statistics.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hdeem_watch.dram.command_trace import read_command_trace
from hdeem_watch.dram.energy import COMPONENTS, core_energy
from hdeem_watch.dram.memspec import load_memspec, preset
from hdeem_watch.dram.stats import CommandStats, RankStats
from hdeem_watch.dram.trace_state import trace_stats
from hdeem_watch.errors import InputError


def _load_helpers():  # type: ignore[no-untyped-def]
    """The DRAMPower-counter adapters of test_energy.py (importlib mode: load by path)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("_energy_helpers", Path(__file__).with_name("test_energy.py"))
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


HELPERS = _load_helpers()


# ---------------------------------------------------------------- literal DRAMPower oracle
class _Interval:
    def __init__(self) -> None:
        self.count, self.start, self.end = 0, None, None

    def is_open(self) -> bool:
        return self.start is not None and self.end is None

    def start_interval(self, t: int) -> None:
        self.start, self.end = t, None

    def start_if_not_running(self, t: int) -> None:
        if not self.is_open():
            self.start_interval(t)

    def close(self, t: int) -> None:
        if self.is_open():
            self.end = t
            self.count += t - self.start  # type: ignore[operator]

    def at(self, t: int) -> int:
        return self.count + t - self.start if self.is_open() and t > self.start else self.count  # type: ignore[operator]


class _Oracle:
    def __init__(self, spec, ranks: int, banks: int) -> None:  # type: ignore[no-untyped-def]
        self.spec, self.queue, self.seq = spec, [], 0
        self.ranks = [{"act": _Interval(), "pdna": _Interval(), "pdnp": _Interval(), "sref": _Interval(),
                       "end_ref": 0, "banks": [{"active": False, "act": _Interval(), "n_act": 0, "n_pre": 0,
                                                "latest_pre": 0, "ref_end": 0} for _ in range(banks)]}
                      for _ in range(ranks)]

    def add(self, t: int, fn) -> None:  # type: ignore[no-untyped-def]
        self.queue.append((t, self.seq, fn))
        self.seq += 1
        self.queue.sort(key=lambda e: (e[0], e[1]))

    def run_queue(self, t: int) -> None:
        while self.queue and self.queue[0][0] <= t:
            self.queue.pop(0)[2]()

    def is_active(self, rank, t: int) -> bool:  # type: ignore[no-untyped-def]
        return any(b["active"] for b in rank["banks"]) or t < rank["end_ref"]

    def pre(self, rank, bank, t: int) -> None:  # type: ignore[no-untyped-def]
        if not bank["active"]:
            return
        bank["n_pre"] += 1
        bank["active"] = False
        bank["act"].close(t)
        bank["latest_pre"] = t
        if not self.is_active(rank, t):
            rank["act"].close(t)

    def earliest(self, rank) -> int:  # type: ignore[no-untyped-def]
        tm = self.spec.timings
        return max([0] + [max(b["act"].start + tm["RCD"] if b["n_act"] and b["act"].start is not None else 0,
                              b["latest_pre"] + tm["RP"] if b["n_pre"] else 0, b["ref_end"]) for b in rank["banks"]])

    def command(self, t: int, name: str, r: int, b: int) -> None:
        self.run_queue(t)
        tm, rank = self.spec.timings, self.ranks[r]
        bank = rank["banks"][b]
        if name == "ACT":
            bank["n_act"] += 1
            bank["active"] = True
            bank["act"].start_interval(t)
            rank["act"].start_if_not_running(t)
        elif name == "PRE":
            self.pre(rank, bank, t)
        elif name == "PREA":
            for each in rank["banks"]:
                self.pre(rank, each, t)
        elif name in ("REFA", "SREFEN"):
            end = t + self.spec.trfc
            rank["end_ref"] = end
            rank["act"].start_if_not_running(t)
            for each in rank["banks"]:
                each["active"] = True
                each["act"].start_if_not_running(t)
                each["ref_end"] = end

                def ref_done(each=each, end=end) -> None:  # type: ignore[no-untyped-def]
                    each["active"] = False
                    each["act"].close(end)
                    if not self.is_active(rank, end):
                        rank["act"].close(end)
                self.add(end, ref_done)
            if name == "SREFEN":
                self.add(end, lambda: rank["sref"].start_interval(end))
        elif name in ("RDA", "WRA"):
            offset = tm["AL"] + tm["RTP"] if name == "RDA" else 4 + tm["WL"] + tm["WR"]
            when = max((bank["act"].start or 0) + tm["RAS"], t + offset)
            self.add(when, lambda: self.pre(rank, bank, when))
        elif name == "SREFEX":
            rank["sref"].close(t)
        elif name in ("PDEA", "PDEP"):
            when = max(t, self.earliest(rank))

            def enter() -> None:
                rank["pdna" if name == "PDEA" else "pdnp"].start_interval(when)
                rank["act"].close(when)
                for each in rank["banks"]:
                    each["act"].close(when)
            self.add(when, enter)
        elif name in ("PDXA", "PDXP"):
            when = max(t, self.earliest(rank))

            def leave() -> None:
                rank["pdna" if name == "PDXA" else "pdnp"].close(when)
                for each in rank["banks"]:
                    if each["active"]:
                        each["act"].start_interval(when)
                if name == "PDXA" and self.is_active(rank, when):
                    rank["act"].start_interval(when)
            self.add(when, leave)

    def stats(self, counts: dict[int, dict[str, int]], end: int) -> CommandStats:
        self.run_queue(end)
        out = []
        for r, rank in enumerate(self.ranks):
            act = rank["act"].at(end)
            pdna, pdnp, sref = rank["pdna"].at(end), rank["pdnp"].at(end), rank["sref"].at(end)
            c = counts[r]
            out.append(RankStats(
                act=c["ACT"], pre=sum(b["n_pre"] for b in rank["banks"]), rd=c["RD"], wr=c["WR"], rda=c["RDA"],
                wra=c["WRA"], ref=c["REFA"] + c["SREFEN"], cycles_total=end, cycles_act=act,
                cycles_pre=end - act - pdna - pdnp - sref, cycles_pdna=pdna, cycles_pdnp=pdnp,
                cycles_sref=sref, bank_active_cycles=sum(b["act"].at(end) for b in rank["banks"])))
        return CommandStats(ranks=tuple(out))


def _random_legal_trace(rng: np.random.Generator, spec, n: int) -> list[tuple[int, str, int, int]]:  # type: ignore[no-untyped-def]
    """Commands a JEDEC-respecting controller could issue (power-down entries may be early)."""
    tm, banks = spec.timings, spec.nbr_of_banks
    state = [{"open": [None] * banks, "free": [0] * banks, "ready": 0, "mode": None, "pd_since_act": [False] * banks}
             for _ in range(spec.nbr_of_ranks)]
    t, out = 0, []
    for _ in range(n):
        t += int(rng.choice([0, 1, 2, 5, 10, 40, 300]))
        r = int(rng.integers(spec.nbr_of_ranks))
        st = state[r]
        if st["mode"] is not None:  # leave power-down / self-refresh
            out.append((t, {"PDEA": "PDXA", "PDEP": "PDXP", "SREFEN": "SREFEX"}[st["mode"]], r, 0))
            if st["mode"] == "SREFEN":
                t = max(t, st["ready"])
                out[-1] = (t, "SREFEX", r, 0)
            st["ready"] = max(st["ready"], t + (0 if rng.random() < 0.3 else tm["XP"]))
            st["mode"] = None
            continue
        t = max(t, st["ready"])
        opened = [k for k in range(banks) if st["open"][k] is not None]
        b = int(rng.choice(opened)) if opened and rng.random() < 0.6 else int(rng.integers(banks))
        idle = all(st["free"][k] <= t for k in range(banks)) and not opened
        choice = rng.random()
        if st["open"][b] is None and st["free"][b] <= t and choice < 0.35:
            out.append((t, "ACT", r, b))
            st["open"][b], st["pd_since_act"][b] = t, False
            st["ready"] = t + int(rng.choice([1, tm["RCD"]]))
        elif st["open"][b] is not None and choice < 0.8:
            name = str(rng.choice(["RD", "WR", "RDA", "WRA", "PRE"]))
            if name in ("RDA", "WRA") and st["pd_since_act"][b]:
                name = "RD"
            out.append((t, name, r, b))
            if name in ("RDA", "WRA", "PRE"):
                offset = tm["RTP"] if name == "RDA" else 4 + tm["WL"] + tm["WR"]
                close = t if name == "PRE" else max(st["open"][b] + tm["RAS"], t + offset)
                st["free"][b], st["open"][b] = close + tm["RP"], None
        elif opened and choice < 0.83:
            out.append((t, "PREA", r, 0))
            for k in opened:
                st["open"][k], st["free"][k] = None, t + tm["RP"]
        elif idle and choice < 0.9:
            name = "SREFEN" if rng.random() < 0.3 else "REFA"
            out.append((t, name, r, 0))
            st["ready"] = t + spec.trfc if name == "REFA" else t + spec.trfc + int(rng.integers(1, 500))
            if name == "SREFEN":
                st["mode"] = "SREFEN"
            for k in range(banks):
                st["free"][k] = t + spec.trfc
        elif choice < 0.95:
            pending = any(st["free"][k] > t for k in range(banks))
            if opened:
                out.append((t, "PDEA", r, 0))
                st["mode"] = "PDEA"
                for k in opened:
                    st["pd_since_act"][k] = True
            elif not pending:
                out.append((t, "PDEP", r, 0))
                st["mode"] = "PDEP"
    out.append((t + int(rng.integers(0, 50)), "END", 0, 0))
    return out


def _write(path: Path, commands: list[tuple[int, str, int, int]]) -> Path:
    path.write_text("".join(f"{t},{name},{r},{b // 4},{b},7,0\n" for t, name, r, b in commands))
    return path


def _oracle_stats(spec, commands: list[tuple[int, str, int, int]]) -> CommandStats:  # type: ignore[no-untyped-def]
    oracle = _Oracle(spec, spec.nbr_of_ranks, spec.nbr_of_banks)
    counts = {r: dict.fromkeys(("ACT", "RD", "WR", "RDA", "WRA", "REFA", "SREFEN"), 0) for r in range(spec.nbr_of_ranks)}
    for t, name, r, b in commands:
        if name == "END":
            continue
        if name in counts[r]:
            counts[r][name] += 1
        oracle.command(t, name, r, b)
    return oracle.stats(counts, commands[-1][0])


def test_reference_traces_give_drampower_counters(drampower_ref: Path, reference_memspec_path,  # type: ignore[no-untyped-def]
                                                  drampower_case: tuple[str, str]) -> None:
    """For every reference trace, counts and cycles per rank equal DRAMPower's internal counters."""
    config, trace = drampower_case
    spec = load_memspec(reference_memspec_path(config))
    internal = json.loads((drampower_ref / "results" / config / f"{trace}.stats.json").read_text())
    ours = trace_stats(spec, read_command_trace(drampower_ref / "traces" / f"{trace}.csv", spec))
    assert ours == HELPERS.stats_from_drampower(internal, spec.nbr_of_banks)


def test_reference_traces_energy_end_to_end(drampower_ref: Path, reference_memspec_path,  # type: ignore[no-untyped-def]
                                            drampower_case: tuple[str, str]) -> None:
    """Trace -> state machine -> energy matches every DRAMPower core component to 1e-9 relative."""
    config, trace = drampower_case
    spec = load_memspec(reference_memspec_path(config))
    cli = json.loads((drampower_ref / "results" / config / f"{trace}.cli.json").read_text())
    energy = core_energy(spec, trace_stats(spec, read_command_trace(drampower_ref / "traces" / f"{trace}.csv")))
    theirs = HELPERS.drampower_components(cli)
    for name in COMPONENTS:
        assert energy.components[name] == pytest.approx(theirs[name], rel=1e-9, abs=1e-25), name


@pytest.mark.parametrize("seed", range(12))
def test_random_legal_traces_match_literal_drampower(tmp_path: Path, seed: int) -> None:
    """Random legal traces (RDA/WRA, PREA, REFA, deferred power-down, self-refresh) match the oracle."""
    rng = np.random.default_rng(seed)
    spec = preset("ddr4-2133-x8-4gb")
    commands = _random_legal_trace(rng, spec, 400)
    ours = trace_stats(spec, read_command_trace(_write(tmp_path / "t.csv", commands), spec))
    assert ours == _oracle_stats(spec, commands)


def test_auto_precharge_and_prea_rules(tmp_path: Path) -> None:
    """RDA closes at max(ACT+RAS, t+AL+RTP), WRA at max(ACT+RAS, t+BL/2+WL+WR); PREA counts open banks only."""
    spec = preset("ddr4-2133-x8-4gb")  # RAS 36, RTP 8, WL 11, WR 16, AL 0
    commands = [(0, "ACT", 0, 0), (15, "RDA", 0, 0),       # closes at max(36, 23) = 36
                (100, "ACT", 0, 1), (130, "RDA", 0, 1),    # closes at max(136, 138) = 138
                (200, "ACT", 0, 2), (215, "WRA", 0, 2),    # closes at max(236, 215+4+11+16=246) = 246
                (300, "ACT", 0, 3), (301, "ACT", 0, 4), (340, "PREA", 0, 0), (341, "PREA", 0, 0),
                (400, "END", 0, 0)]
    rank = trace_stats(spec, read_command_trace(_write(tmp_path / "t.csv", commands)))
    r0 = rank.ranks[0]
    assert (r0.act, r0.pre, r0.rda, r0.wra) == (5, 5, 2, 1)
    assert r0.cycles_act == 36 + 38 + 46 + 40
    assert r0.bank_active_cycles == 36 + 38 + 46 + 40 + 39
    assert r0.cycles_pre == 400 - r0.cycles_act


def test_power_down_entry_is_deferred_to_earliest(tmp_path: Path) -> None:
    """PDEA right after ACT enters at ACT+RCD; PDEP during a refresh enters at the refresh end."""
    spec = preset("ddr4-2133-x8-4gb")  # RCD 15, RFC 278
    commands = [(0, "ACT", 0, 0), (5, "PDEA", 0, 0), (100, "PDXA", 0, 0), (110, "PRE", 0, 0),
                (200, "REFA", 0, 0), (210, "PDEP", 0, 0), (1000, "PDXP", 0, 0), (2000, "END", 0, 0)]
    r0 = trace_stats(spec, read_command_trace(_write(tmp_path / "t.csv", commands))).ranks[0]
    assert r0.cycles_pdna == 100 - 15
    assert r0.cycles_pdnp == 1000 - 478
    assert r0.cycles_act == 15 + 10 + 278
    assert r0.ref == 1 and r0.pre == 1


@pytest.mark.parametrize(("lines", "message"), [
    ("0,PDXA,0,0,0,0,0\n", "line 1: PDXA without a preceding PDEA"),
    ("0,PDEP,0,0,0,0,0\n5,PDXA,0,0,0,0,0\n", r"line 2: PDXA without a preceding PDEA \(the rank is in PDEP\)"),
    ("0,SREFEN,0,0,0,0,0\n500,PDEA,0,0,0,0,0\n", "line 2: PDEA while the rank is in SREFEN"),
    ("0,SREFEX,1,0,0,0,0\n", "line 1: SREFEX without a preceding SREFEN"),
])
def test_power_state_order_errors(tmp_path: Path, lines: str, message: str) -> None:
    """Exits without their entry, and entries while already in a low-power state, are bad input."""
    path = tmp_path / "t.csv"
    path.write_text(lines)
    with pytest.raises(InputError, match=message):
        trace_stats(preset("ddr4-2133-x8-4gb"), read_command_trace(path))


def test_open_states_at_end_are_counted_to_t(tmp_path: Path) -> None:
    """A bank still open, a power-down or self-refresh still running at END count up to END."""
    spec = preset("ddr4-2133-x8-4gb")
    commands = [(0, "ACT", 0, 3), (0, "SREFEN", 1, 0), (1000, "END", 0, 0)]
    stats = trace_stats(spec, read_command_trace(_write(tmp_path / "t.csv", commands)))
    assert stats.ranks[0].cycles_act == 1000 and stats.ranks[0].bank_active_cycles == 1000
    assert stats.ranks[1].cycles_act == 278 and stats.ranks[1].cycles_sref == 1000 - 278
    assert stats.ranks[1].ref == 1 and stats.ranks[1].cycles_pre == 0


def test_benchmark_trace_matches_oracle(tmp_path: Path) -> None:
    """The benchmark's synthetic trace is legal and the fast path agrees with the literal oracle on it."""
    import importlib.util

    bench_path = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_energy.py"
    spec_ = importlib.util.spec_from_file_location("_bench_energy", bench_path)
    assert spec_ is not None and spec_.loader is not None
    bench = importlib.util.module_from_spec(spec_)
    spec_.loader.exec_module(bench)
    path = tmp_path / "bench.csv"
    counts = bench.write_trace(path, 20_000, seed=3)
    spec = preset("ddr4-2133-x8-4gb")
    trace = read_command_trace(path, spec)
    assert len(trace) == sum(counts.values()) and trace.count("PDEP") == counts["PDEP"] > 0
    commands = [(int(t), ("ACT", "PRE", "PREA", "REFA", "RD", "RDA", "WR", "WRA", "PDEA", "PDXA", "PDEP", "PDXP",
                          "SREFEN", "SREFEX", "END", "NOP")[c], int(r), int(b))
                for t, c, r, b in zip(trace.cycle, trace.cmd, trace.rank, trace.bank)]
    assert trace_stats(spec, trace) == _oracle_stats(spec, commands)
