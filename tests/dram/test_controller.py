"""Controller model: row-buffer policies, DDR4 spacing, refresh, DRAMPower trace, kernel statistics."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hdeem_watch.dram.command_emit import write_drampower_trace
from hdeem_watch.dram.command_trace import read_command_trace
from hdeem_watch.dram.controller import simulate
from hdeem_watch.dram.energy import core_energy
from hdeem_watch.dram.kernels import kernel_requests, kernel_stats
from hdeem_watch.dram.mapping import AddressMapping, Fields, Geometry
from hdeem_watch.dram.memspec import load_memspec
from hdeem_watch.dram.trace_state import trace_stats
from hdeem_watch.errors import InputError

# One worker runs the module, so its module-scoped fixture is built once, not once per worker.
pytestmark = pytest.mark.xdist_group("dram-controller")

REFERENCE = Path(__file__).resolve().parents[1] / "data" / "ramulator"


@pytest.fixture(scope="module")
def spec():  # type: ignore[no-untyped-def]
    return load_memspec(REFERENCE / "ddr4_2133P_8Gb_x8_2r_8dev.json")


def _addresses(spec, rank, bankgroup, bank, row, column):  # type: ignore[no-untyped-def]
    mapping = AddressMapping(Geometry.from_spec(spec), "RoBaRaCoCh")
    n = len(row)
    fields = Fields(channel=np.zeros(n, np.int64), rank=np.asarray(rank), bankgroup=np.asarray(bankgroup),
                    bank=np.asarray(bank), row=np.asarray(row), column=np.asarray(column),
                    flat_bank=np.asarray(bankgroup) * 4 + np.asarray(bank))
    return mapping.encode(fields)


def test_open_page_hits_and_conflict_spacing(spec) -> None:  # type: ignore[no-untyped-def]
    """Same row: one ACT then hits every tCCD_L; another row in the same bank: PRE after tRTP, ACT after tRP."""
    t = spec.timings
    addresses = _addresses(spec, [0] * 4, [0] * 4, [0] * 4, [7, 7, 7, 9], [0, 1, 2, 0])
    result = simulate(spec, addresses, np.zeros(4, dtype=bool), keep_commands=True)
    assert (result.row_hits, result.row_misses, result.row_conflicts) == (2, 1, 1)
    cols = result.commands.col_cycle
    assert np.diff(cols)[:2].tolist() == [t["CCD_L"], t["CCD_L"]]
    assert result.stats.ranks[0].act == 2 and result.stats.ranks[0].pre == 1
    assert cols[3] - cols[2] >= t["RTP"] + t["RP"] + t["RCD"] - 12  # 12 = hidden_bank of the default scheduler
    assert result.commands.act_cycle[1] - result.commands.pre_cycle[0] == t["RP"]


def test_bank_groups_interleave_at_ccd_s(spec) -> None:  # type: ignore[no-untyped-def]
    """Reads alternating between bank groups are spaced tCCD_S, within one group tCCD_L."""
    n = 64
    alternating = _addresses(spec, [0] * n, [i % 2 for i in range(n)], [0] * n, [3] * n, [i // 2 for i in range(n)])
    same = _addresses(spec, [0] * n, [0] * n, [0] * n, [3] * n, list(range(n)))
    fast = simulate(spec, alternating, np.zeros(n, dtype=bool), keep_commands=True)
    slow = simulate(spec, same, np.zeros(n, dtype=bool), keep_commands=True)
    assert np.median(np.diff(fast.commands.col_cycle)) == spec.timings["CCD_S"]
    assert np.median(np.diff(slow.commands.col_cycle)) == spec.timings["CCD_L"]
    assert fast.cycles < slow.cycles


def test_closed_page_precharges_with_rda(spec) -> None:  # type: ignore[no-untyped-def]
    """Closed page: every row is closed by an auto-precharge; no conflicts; more activations than open page."""
    addresses, is_write = kernel_requests("copy", 8 * 4096, threads=4)
    opened = simulate(spec, addresses, is_write, policy="open")
    closed = simulate(spec, addresses, is_write, policy="closed")
    stats = closed.stats
    assert closed.row_conflicts == 0
    assert stats.total("rda") + stats.total("wra") > 0
    assert stats.total("act") >= opened.stats.total("act")
    assert stats.total("rd") + stats.total("rda") == closed.reads == opened.reads
    assert opened.stats.total("rda") == 0


def test_refresh_every_refi_closes_rows(spec) -> None:  # type: ignore[no-untyped-def]
    """Each rank gets floor(T / tREFI) refreshes; in a read stream each refresh costs activations."""
    addresses, is_write = kernel_requests("read", 8 * 200_000)
    result = simulate(spec, addresses, is_write)
    refi = spec.timings["REFI"]
    for rank in result.stats.ranks:
        assert rank.ref == result.cycles // refi
        assert rank.cycles_act + rank.cycles_pre == rank.cycles_total == result.cycles
    rows = 200_000 // 128
    assert result.stats.total("act") > rows + result.stats.ranks[0].ref * 0.5


@pytest.mark.parametrize("policy", ["open", "closed"])
@pytest.mark.parametrize("kernel", ["read", "add"])
def test_drampower_trace_gives_the_same_energy(tmp_path: Path, spec, policy: str, kernel: str) -> None:  # type: ignore[no-untyped-def]
    """The emitted DRAMPower trace, read back by the energy model, gives the energy of the statistics.

    Open page: identical. Closed page: within 2e-5 (a few implicit precharges next to a refresh are
    counted differently; see docs/dram-stats.md).
    """
    addresses, is_write = kernel_requests(kernel, 8 * 30_000, threads=3)
    result = simulate(spec, addresses, is_write, policy=policy, keep_commands=True)
    path = tmp_path / "trace.csv"
    write_drampower_trace(path, result)
    from_trace = trace_stats(spec, read_command_trace(path))
    ours = core_energy(spec, result.stats).core_j
    theirs = core_energy(spec, from_trace).core_j
    assert ours == pytest.approx(theirs, rel=1e-12 if policy == "open" else 2e-5)
    for a, b in zip(result.stats.ranks, from_trace.ranks):
        assert (a.act, a.rd, a.wr, a.rda, a.wra, a.ref) == (b.act, b.rd, b.wr, b.rda, b.wra, b.ref)


@pytest.mark.slow
def test_kernel_stats_prefix_scales_to_the_full_run(spec) -> None:  # type: ignore[no-untyped-def]
    """kernel_stats on a prefix agrees with a full simulation within 1 %, and repeat/channels scale linearly."""
    elements = 8 * 300_000
    full = simulate(spec, *kernel_requests("copy", elements, threads=4))
    model = kernel_stats(spec, "copy", elements, 4, max_requests=120_000)
    assert model.reads == full.reads and model.writes == full.writes
    assert model.stats.total("act") == pytest.approx(full.stats.total("act"), rel=0.01)
    assert model.cycles == pytest.approx(full.cycles, rel=0.01)
    twice = kernel_stats(spec, "copy", elements, 4, repeat=2, max_requests=120_000)
    assert twice.stats.total("act") == pytest.approx(2 * model.stats.total("act"))
    split = kernel_stats(spec, "copy", elements, 4, channels=4, max_requests=120_000)
    assert split.reads == pytest.approx(model.reads / 4)
    empty = kernel_stats(spec, "read", 0, 1)
    assert empty.cycles == 0 and empty.stats.total("act") == 0


def test_bad_arguments_are_input_errors(spec) -> None:  # type: ignore[no-untyped-def]
    """An unknown policy, mismatched arrays or a bad mapping is an InputError."""
    addresses, is_write = kernel_requests("read", 64)
    with pytest.raises(InputError, match="policy"):
        simulate(spec, addresses, is_write, policy="lazy")
    with pytest.raises(InputError, match="write flags"):
        simulate(spec, addresses, is_write[:-1])
    with pytest.raises(InputError, match="mapping"):
        simulate(spec, addresses, is_write, mapping="RoRoCo")
    with pytest.raises(InputError, match="threads"):
        kernel_stats(spec, "read", 64, 0)


def test_chunked_simulation_matches_one_piece(tmp_path: Path, spec, monkeypatch: pytest.MonkeyPatch) -> None:  # type: ignore[no-untyped-def]
    """Serving a stream in chunks changes the statistics by a handful of activations, and its trace still agrees."""
    import hdeem_watch.dram.controller as controller

    addresses, is_write = kernel_requests("triad", 8 * 40_000, threads=2)
    whole = simulate(spec, addresses, is_write)
    monkeypatch.setattr(controller, "CHUNK_REQUESTS", 20_000)
    chunked = simulate(spec, addresses, is_write, keep_commands=True)
    assert chunked.requests == whole.requests and chunked.reads == whole.reads
    assert chunked.stats.total("act") == pytest.approx(whole.stats.total("act"), abs=6 * 32)
    assert chunked.cycles == pytest.approx(whole.cycles, rel=0.01)
    for rank in chunked.stats.ranks:
        assert rank.cycles_total == chunked.cycles
    path = tmp_path / "chunked.csv"
    write_drampower_trace(path, chunked)
    from_trace = trace_stats(spec, read_command_trace(path))
    assert core_energy(spec, chunked.stats).core_j == pytest.approx(core_energy(spec, from_trace).core_j, rel=1e-12)


@pytest.mark.parametrize("policy", ["open", "closed"])
def test_pipelined_chunks_give_the_same_result(spec, policy: str, monkeypatch: pytest.MonkeyPatch) -> None:  # type: ignore[no-untyped-def]
    """Preparing the next chunk in a second thread changes nothing: counts, cycles and commands are equal."""
    import hdeem_watch.dram.controller as controller

    monkeypatch.setattr(controller, "CHUNK_REQUESTS", 1 << 12)
    addresses, is_write = kernel_requests("triad", 8 * 9000, threads=3)
    results = []
    for pipeline in (True, False):
        monkeypatch.setattr(controller, "PIPELINE", pipeline)
        results.append(simulate(spec, addresses, is_write, policy=policy, keep_commands=True))
    threaded, serial = results
    assert threaded.stats == serial.stats and threaded.cycles == serial.cycles
    assert (threaded.row_hits, threaded.row_misses, threaded.row_conflicts) == (
        serial.row_hits, serial.row_misses, serial.row_conflicts)
    assert threaded.commands is not None and serial.commands is not None
    for name in ("act_cycle", "pre_cycle", "col_cycle", "col_column", "col_auto"):
        assert np.array_equal(getattr(threaded.commands, name), getattr(serial.commands, name))
