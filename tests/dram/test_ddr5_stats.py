"""DDR5 command statistics (issue 30): sub-channels, BL16 bursts, refresh per mode, DDR5 timings, CLI."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hdeem_watch.cli import main
from hdeem_watch.dram.controller import simulate
from hdeem_watch.dram.ddr5_channel import LINE_BYTES, SUBCHANNELS, kernel_stats_ddr5, subchannel_spec
from hdeem_watch.dram.energy_ddr5 import core_energy_ddr5
from hdeem_watch.dram.kernels import KERNELS, kernel_requests, kernel_traffic
from hdeem_watch.dram.mapping import Geometry
from hdeem_watch.dram.memspec_ddr5 import MemSpecDDR5, parse_memspec_ddr5
from hdeem_watch.dram.request_traces import write_requests
from hdeem_watch.dram.stats import CommandStats, RankStats, stretch_stats
from hdeem_watch.errors import InputError

ROOT = Path(__file__).resolve().parents[2]
TOY = ROOT / "examples" / "ddr5_drampower_test.json"
TWO_RANK = ROOT / "tests" / "data" / "drampower_ddr5" / "memspecs" / "ddr5_2r_allterms.json"

#: JESD79-5 DDR5-4800B timings (tCK 0.4167 ns; 16 Gb die: tRFC1 295 ns, tRFC2 160 ns, tRFCsb 130 ns,
#: tREFI1 3.9 µs, tREFI2 1.95 µs), in cycles. The currents stay DRAMPower's test values: these
#: tests judge counts, not joules.
DDR5_4800: dict[str, Any] = {
    "tCK": 1 / 2.4e9, "RL": 40, "WL": 38, "RCD": 40, "RP": 40, "RAS": 77, "RTP": 18, "WR": 72,
    "CCD_S_slr": 8, "CCD_L_slr": 12, "CCD_L_WR_slr": 48, "WTR_S": 6, "WTR_L": 24, "RRD_S_slr": 8,
    "RRD_L_slr": 12, "FAW_slr": 32, "REFI1": 9360, "REFI2": 4680, "RFC1_slr": 708, "RFC2_slr": 384,
    "RFCsb_slr": 312, "RTRS": 2,
}


def ddr5_spec(source: Path = TOY, *, ref_mode: int = 1, width: int = 8, **timings: int) -> MemSpecDDR5:
    """``source`` (a DRAMPower DDR5 memspec) as a 32-bit BL16 sub-channel with DDR5-4800 timings."""
    data = json.loads(source.read_text())
    arch = data["memspec"]["memarchitecturespec"]
    groups = 4 if width == 16 else 8  # JESD79-5: x16 has 4 bank groups, x4/x8 have 8 (4 banks each)
    arch.update(burstLength=16, maxBurstLength=16, width=width, nbrOfDevices=32 // width, nbrOfBankGroups=groups,
                nbrOfBanks=4 * groups, RefMode=ref_mode)
    data["memspec"]["memtimingspec"].update(copy.deepcopy(DDR5_4800), **timings)
    return parse_memspec_ddr5(data, where=str(source))


@pytest.mark.parametrize("kernel", KERNELS)
def test_kernel_reads_writes_are_the_kernels_bytes(kernel: str) -> None:
    """One 64-byte burst per line per sub-channel: reads/writes × 64 × sub-channels = the kernel's bytes."""
    spec = ddr5_spec()
    elements, channels = 3_000_000, 2
    model = kernel_stats_ddr5(spec, kernel, elements, 8, channels=channels)
    traffic = kernel_traffic(kernel, elements)
    assert model.reads * LINE_BYTES * SUBCHANNELS * channels == traffic.lines_read * LINE_BYTES
    assert model.writes * LINE_BYTES * SUBCHANNELS * channels == traffic.lines_written * LINE_BYTES
    stats = model.stats
    assert stats.total("rd") + stats.total("rda") == pytest.approx(model.reads, rel=1e-9)
    assert stats.total("wr") + stats.total("wra") == pytest.approx(model.writes, rel=1e-9)


def test_small_kernel_counts_exact_bursts() -> None:
    """A run that fits the simulated prefix: RD/WR are exactly the lines of the sub-channel."""
    model = kernel_stats_ddr5(ddr5_spec(), "triad", 1_000_000, 4)
    lines = kernel_traffic("triad", 1_000_000)
    assert model.stats.total("rd") == lines.lines_read / SUBCHANNELS
    assert model.stats.total("wr") == lines.lines_written / SUBCHANNELS


@pytest.mark.parametrize("ref_mode, refi", [(1, 9360), (2, 4680)])
def test_refresh_count_matches_the_window(ref_mode: int, refi: int) -> None:
    """REF per rank = window / tREFI of the refresh mode (REFI1 or REFI2), on 1 and 2 ranks."""
    for source in (TOY, TWO_RANK):
        model = kernel_stats_ddr5(ddr5_spec(source, ref_mode=ref_mode), "copy", 4_000_000, 4)
        for rank in model.stats.ranks:
            expected = rank.cycles_total / refi
            assert expected > 100
            # counted per simulated prefix and scaled: within one prefix refresh of the window
            assert abs(rank.ref - expected) <= model.scale + 1e-9


def test_refresh_mode_two_refreshes_twice_as_often_for_less_time() -> None:
    """RefMode 2 uses REFI2/RFC2: about twice the REFs of mode 1 on the same traffic."""
    one = kernel_stats_ddr5(ddr5_spec(ref_mode=1), "read", 2_000_000, 2).stats.ranks[0]
    two = kernel_stats_ddr5(ddr5_spec(ref_mode=2), "read", 2_000_000, 2).stats.ranks[0]
    assert two.ref / two.cycles_total == pytest.approx(2 * one.ref / one.cycles_total, rel=0.02)


def test_bank_groups_from_the_memarchitecturespec() -> None:
    """x8: 8 bank groups × 4 banks; x16: 4 × 4; two 32-bit sub-channels with 64-byte bursts."""
    for width, groups in ((8, 8), (4, 8), (16, 4)):
        geometry = Geometry.from_spec(subchannel_spec(ddr5_spec(width=width)))
        assert (geometry.channels, geometry.bankgroups, geometry.banks_per_group) == (2, groups, 4)
        assert geometry.transaction_bytes == LINE_BYTES


def _one_group_writes(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Writes to consecutive columns of one row of one bank, all on sub-channel 0."""
    return (np.arange(n, dtype=np.uint64) * (2 * LINE_BYTES), np.ones(n, dtype=bool))


def test_ccd_l_wr_spaces_writes_in_a_bank_group() -> None:
    """Back-to-back writes to one bank group are tCCD_L_WR apart (DDR4 used tCCD_L)."""
    addresses, writes = _one_group_writes(64)
    slow = simulate(subchannel_spec(ddr5_spec(CCD_L_WR_slr=48)), addresses, writes)
    fast = simulate(subchannel_spec(ddr5_spec(CCD_L_WR_slr=12)), addresses, writes)
    assert slow.writes == fast.writes == 64
    assert slow.cycles - fast.cycles == 63 * (48 - 12)


def test_bad_burst_is_one_clear_error() -> None:
    """DRAMPower's toy (one x8 device, BL8: 8 bytes per burst) is not a 64-byte sub-channel."""
    data = json.loads(TOY.read_text())
    with pytest.raises(InputError, match=r"burst carries 8 bytes.*64-byte line"):
        subchannel_spec(parse_memspec_ddr5(data))
    with pytest.raises(InputError, match=r"memtimingspec\.REFI2 = 0"):
        subchannel_spec(ddr5_spec(ref_mode=2, REFI2=0))


@pytest.mark.parametrize("ref_mode, refi", [(1, 9360), (2, 4680)])
def test_stretch_fills_an_idle_ddr5_rank_from_refi_of_the_mode(ref_mode: int, refi: int) -> None:
    """stretch_stats: an idle DDR5 rank is refreshed every REFI1/REFI2 (was 0: DDR4's REFI key is absent)."""
    spec = ddr5_spec(TWO_RANK, ref_mode=ref_mode)
    busy = RankStats(act=4, pre=4, rd=64, ref=1, cycles_total=10_000, cycles_act=500, cycles_pre=9_500)
    stretched = stretch_stats(spec, CommandStats(ranks=(busy, RankStats())), 1e-3)
    idle = stretched.ranks[1]
    assert idle.cycles_total == pytest.approx(1e-3 / spec.tck_s)
    assert idle.ref == pytest.approx(idle.cycles_total / refi)
    assert core_energy_ddr5(spec, stretched).components["ref_j"] > 0


def _write(tmp_path: Path, spec: MemSpecDDR5) -> Path:
    path = tmp_path / "ddr5.json"
    path.write_text(json.dumps(spec.to_json_dict()))
    return path


def test_cli_kernel_ddr5_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """model kernel on a DDR5 memspec: one sub-channel's bursts, refresh, energy with refsb_j."""
    memspec = _write(tmp_path, ddr5_spec())
    assert main(["model", "kernel", "--kernel", "triad", "--elements", "1e6", "--threads", "4",
                 "--memspec", str(memspec), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    lines = kernel_traffic("triad", 1_000_000)
    assert data["subchannels"] == 2 and data["refsb"] == 0
    assert (data["reads"], data["writes"]) == (lines.lines_read / 2, lines.lines_written / 2)
    assert (data["rd"], data["wr"]) == (data["reads"], data["writes"])
    assert data["ref"] == pytest.approx(data["cycles"] / 9360, abs=2 * data["prefix_scale"])
    assert "refsb_j" in data["energy"]["components"] and data["energy"]["core_j"] > 0


def test_cli_stats_ddr5_serves_both_subchannels(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """model stats on a DDR5 memspec: every request served on one of the two sub-channels; energy is their sum."""
    trace = tmp_path / "copy.trace"
    addresses, is_write = kernel_requests("copy", 8 * 20_000, threads=2)
    write_requests(trace, addresses, is_write)
    memspec = _write(tmp_path, ddr5_spec(TWO_RANK))
    assert main(["model", "stats", "--trace", str(trace), "--format", "ramulator", "--memspec", str(memspec),
                 "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert (data["requests"], data["reads"], data["writes"]) == (addresses.size, int((~is_write).sum()),
                                                                 int(is_write.sum()))
    assert data["rd"] == data["reads"] and data["wr"] == data["writes"]
    halves = data["subchannels"]
    assert len(halves) == 2 and len(data["ranks"]) == 4
    assert halves[0]["requests"] == halves[1]["requests"] == addresses.size // 2
    assert data["energy"]["core_j"] == pytest.approx(sum(h["energy"]["core_j"] for h in halves), rel=1e-12)


def test_cli_kernel_ddr5_bad_burst_exits_2(capsys: pytest.CaptureFixture[str]) -> None:
    """The toy memspec (8-byte bursts) is refused on one line, exit 2."""
    assert main(["model", "kernel", "--kernel", "copy", "--elements", "1e5", "--threads", "1",
                 "--memspec", str(TOY)]) == 2
    err = capsys.readouterr().err
    assert "64-byte line" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_cli_stats_ddr5_table_names_the_subchannels(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The table labels each rank with its sub-channel; --emit-drampower is refused on one line (exit 2)."""
    trace = tmp_path / "read.trace"
    write_requests(trace, *kernel_requests("read", 8 * 4_000))
    memspec = _write(tmp_path, ddr5_spec())
    assert main(["model", "stats", "--trace", str(trace), "--format", "ramulator", "--memspec", str(memspec)]) == 0
    out = capsys.readouterr().out
    assert "sub-channel 0 rank 0: act" in out and "sub-channel 1 rank 0: act" in out
    assert main(["model", "stats", "--trace", str(trace), "--format", "ramulator", "--memspec", str(memspec),
                 "--emit-drampower", str(tmp_path / "out.csv")]) == 2
    assert "not available for a DDR5 memspec" in capsys.readouterr().err
