"""Benchmark: energy of a 10 M-command DRAMPower trace, end to end through the CLI.

Builds a synthetic but legal DDR4 trace (2 ranks x 16 banks; per row an ACT, 8-64 reads/writes
with 64-bit hex data, then PRE or an auto-precharging RDA/WRA; REFA on both ranks every REFI;
occasional precharge power-down of the idle rank) in a temporary directory, then times
``hdeem-watch model energy --memspec ddr4-2133-x8-4gb --trace T.csv --json`` as a real subprocess
(interpreter start-up, imports, parsing, state machine, energy, JSON) and reads its peak RSS.

Target (issue 2 / DESIGN.md section 8): >= 3 M commands/s end to end (5x the DRAMPower v6.2 CLI's
0.6 M/s on this kind of machine, from reference/drampower/README.md) and < 1 GB peak RSS.

    python3 benchmarks/bench_energy.py            # 10 M commands
    python3 benchmarks/bench_energy.py --quick    # 1 M commands
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

DRAMPOWER_CMD_PER_S = 0.6e6  # DRAMPower v6.2 CLI, 10 M commands in 16.6 s (reference README)
TARGET_CMD_PER_S = 3.0e6
TARGET_RSS_BYTES = 1 << 30
NAMES = ("ACT", "PRE", "RD", "WR", "RDA", "WRA", "REFA", "PDEP", "PDXP", "END")
RCD, RAS, RP, CCD, CLOSE_AFTER, RFC, REFI = 15, 36, 15, 6, 31, 278, 8320


def _digits(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Right-aligned ASCII digits (N x W) of non-negative integers and each one's digit count."""
    values = values.astype(np.int64)
    width = max(1, len(str(int(values.max(initial=0)))))
    out = np.empty((values.size, width), np.uint8)
    rest = values.copy()
    for k in range(width - 1, -1, -1):
        out[:, k] = 48 + rest % 10
        rest //= 10
    length = np.maximum(1, np.floor(np.log10(np.maximum(values, 1))).astype(np.int64) + 1)
    return out, length


def _format_lines(cycle: np.ndarray, cmd: np.ndarray, rank: np.ndarray, bank: np.ndarray, row: np.ndarray,
                  col: np.ndarray, data: np.ndarray | None) -> bytes:
    """CSV bytes for these commands (vectorised: one boolean-mask gather, no Python per line)."""
    blocks: list[np.ndarray] = []
    masks: list[np.ndarray] = []
    n = cycle.size
    comma = np.full((n, 1), 44, np.uint8)
    true1 = np.ones((n, 1), bool)

    def number(values: np.ndarray) -> None:
        digits, length = _digits(values)
        width = digits.shape[1]
        blocks.append(digits)
        masks.append(np.arange(width)[None, :] >= (width - length)[:, None])

    number(cycle)
    blocks.append(comma)
    masks.append(true1)
    table = np.zeros((len(NAMES), 4), np.uint8)
    for i, name in enumerate(NAMES):
        table[i, :len(name)] = np.frombuffer(name.encode(), np.uint8)
    blocks.append(table[cmd])
    masks.append(table[cmd] != 0)
    for values in (rank, bank // 4, bank, row, col):
        blocks.append(comma)
        masks.append(true1)
        number(values)
    if data is not None:
        has = (cmd == NAMES.index("RD")) | (cmd == NAMES.index("WR")) | (cmd == NAMES.index("RDA")) | (
            cmd == NAMES.index("WRA"))
        blocks.append(comma)
        masks.append(has[:, None])
        blocks.append(data)
        masks.append(np.repeat(has[:, None], data.shape[1], axis=1))
    blocks.append(np.full((n, 1), 10, np.uint8))
    masks.append(true1)
    return np.hstack(blocks)[np.hstack(masks)].tobytes()


def write_trace(path: Path, n_commands: int, seed: int = 0) -> dict[str, int]:
    """Write a legal synthetic trace of about ``n_commands`` lines; returns the count per command."""
    rng = np.random.default_rng(seed)
    n_blocks = max(1, n_commands // 38)
    k = rng.integers(8, 65, n_blocks)  # column commands per row
    auto = rng.random(n_blocks) < 0.1
    rank = (np.arange(n_blocks) // 7) % 2
    bank = rng.integers(0, 16, n_blocks)
    row = rng.integers(0, 32768, n_blocks)
    duration = np.maximum(RAS, RCD + CCD * (k - 1) + CLOSE_AFTER) + RP
    refresh = (np.arange(n_blocks) % max(1, REFI // int(duration.mean())) == 0)
    pdn = (np.arange(n_blocks) % 64 == 32) & ~refresh
    start = np.cumsum(duration + refresh * (RFC + 2)) - duration  # refresh happens before the block
    # per block: [REFA r0, REFA r1]? [PDEP other]? ACT, k x RD/WR, PRE? [PDXP other]?
    per_block = k + 1 + (~auto) + 2 * refresh + 2 * pdn
    total = int(per_block.sum())
    first = np.cumsum(per_block) - per_block
    cycle = np.empty(total + 1, np.int64)
    cmd = np.empty(total + 1, np.uint8)
    rk = np.empty(total + 1, np.int64)
    bk = np.zeros(total + 1, np.int64)
    rw = np.zeros(total + 1, np.int64)
    cl = np.zeros(total + 1, np.int64)
    # position of the ACT of each block
    act_pos = first + 2 * refresh + pdn
    ref_pos = first[refresh]
    for j in (0, 1):
        cycle[ref_pos + j] = start[refresh] - RFC - 2 + j
        cmd[ref_pos + j] = NAMES.index("REFA")
        rk[ref_pos + j] = j
    pd_pos = first[pdn] + 2 * refresh[pdn]
    cycle[pd_pos] = start[pdn]
    cmd[pd_pos] = NAMES.index("PDEP")
    rk[pd_pos] = 1 - rank[pdn]
    cycle[act_pos] = start
    cmd[act_pos] = NAMES.index("ACT")
    rk[act_pos], bk[act_pos], rw[act_pos] = rank, bank, row
    # column commands
    block_of = np.repeat(np.arange(n_blocks), k)
    j = np.arange(block_of.size) - np.repeat(np.cumsum(k) - k, k)
    col_pos = act_pos[block_of] + 1 + j
    write = rng.random(block_of.size) < 0.3
    last = j == k[block_of] - 1
    is_auto = last & auto[block_of]
    cycle[col_pos] = start[block_of] + RCD + CCD * j
    cmd[col_pos] = np.where(write, np.where(is_auto, NAMES.index("WRA"), NAMES.index("WR")),
                            np.where(is_auto, NAMES.index("RDA"), NAMES.index("RD")))
    rk[col_pos], bk[col_pos], rw[col_pos] = rank[block_of], bank[block_of], row[block_of]
    cl[col_pos] = (8 * j) % 1024
    pre = ~auto
    pre_pos = act_pos[pre] + 1 + k[pre]
    cycle[pre_pos] = start[pre] + duration[pre] - RP
    cmd[pre_pos] = NAMES.index("PRE")
    rk[pre_pos], bk[pre_pos], rw[pre_pos] = rank[pre], bank[pre], row[pre]
    px_pos = act_pos[pdn] + 1 + k[pdn] + pre[pdn]
    cycle[px_pos] = start[pdn] + duration[pdn] - RP
    cmd[px_pos] = NAMES.index("PDXP")
    rk[px_pos] = 1 - rank[pdn]
    cycle[total] = start[-1] + duration[-1] + 100
    cmd[total] = NAMES.index("END")
    rk[total] = 0
    hexdigits = np.frombuffer(b"0123456789abcdef", np.uint8)
    with open(path, "wb") as out:
        for lo in range(0, total + 1, 1_000_000):
            hi = min(lo + 1_000_000, total + 1)
            data = hexdigits[rng.integers(0, 16, (hi - lo, 16))]
            out.write(_format_lines(cycle[lo:hi], cmd[lo:hi], rk[lo:hi], bk[lo:hi], rw[lo:hi], cl[lo:hi], data))
    counts = np.bincount(cmd, minlength=len(NAMES))
    return {name: int(counts[i]) for i, name in enumerate(NAMES)}


_WARM = """
import io, sys, time, contextlib
from hdeem_watch.cli import build_parser, main
build_parser()
t0, c0 = time.perf_counter(), time.process_time()
with contextlib.redirect_stdout(io.StringIO()):
    code = main(sys.argv[1:])
print(time.perf_counter() - t0, time.process_time() - c0, file=sys.stderr)
sys.exit(code)
"""


def _run_measured(argv: list[str], stdout_path: Path) -> tuple[int, float, int, float]:
    """Run ``argv`` with stdout to a file; (exit status, wall s, that child's peak RSS bytes, its CPU s)."""
    with open(stdout_path, "wb") as out:
        t0 = time.perf_counter()
        child = subprocess.Popen(argv, stdout=out, stderr=subprocess.PIPE)
        _, status, usage = os.wait4(child.pid, 0)
        wall_s = time.perf_counter() - t0
        child.returncode = os.waitstatus_to_exitcode(status)
    return child.returncode, wall_s, usage.ru_maxrss * 1024, usage.ru_utime + usage.ru_stime


def main() -> int:
    """Build the trace (in a child process, so this one stays small), run the CLI once, print the figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="1 M commands instead of 10 M")
    parser.add_argument("--commands", type=int, default=None, help="number of commands (default 10 M)")
    parser.add_argument("--write", metavar="PATH", help=argparse.SUPPRESS)  # internal: build the trace only
    args = parser.parse_args()
    n = args.commands or (1_000_000 if args.quick else 10_000_000)
    if args.write:
        print(json.dumps(write_trace(Path(args.write), n)))
        return 0
    with tempfile.TemporaryDirectory(prefix="bench_energy_") as tmp:
        path = Path(tmp) / "trace.csv"
        t0 = time.perf_counter()
        built = subprocess.run([sys.executable, __file__, "--write", str(path), "--commands", str(n)],
                               capture_output=True, text=True, check=True)
        counts = json.loads(built.stdout)
        built_s = time.perf_counter() - t0
        lines = sum(counts.values())
        size = path.stat().st_size
        print(f"trace: {lines:,} commands, {size / 1e6:.0f} MB, built in {built_s:.1f} s")
        argv = [sys.executable, "-m", "hdeem_watch", "model", "energy", "--memspec", "ddr4-2133-x8-4gb",
                "--trace", str(path), "--json"]
        _, startup_s, _, startup_cpu_s = _run_measured([*argv[:5], "--help"], Path(tmp) / "help.txt")
        code, wall_s, rss, cpu_s = _run_measured(argv, Path(tmp) / "out.json")
        # the same CLI call in a process whose imports are already done: the model's own rate
        warm = subprocess.run([sys.executable, "-c", _WARM, *argv[3:]], capture_output=True, text=True, check=True)
        warm_s, warm_cpu_s = map(float, warm.stderr.strip().splitlines()[-1].split())
        if code != 0:
            print(f"model energy failed with exit code {code}", file=sys.stderr)
            return 1
        data = json.loads((Path(tmp) / "out.json").read_text())
        modelled = {name: sum(rank[name.lower()] for rank in data["counts"]) for name in ("ACT", "RD", "WR")}
        assert modelled == {name: counts[name] for name in ("ACT", "RD", "WR")}, (modelled, counts)
    rate = lines / wall_s
    print(f"end to end (subprocess, incl. start-up): {wall_s:.2f} s -> {rate / 1e6:.2f} M commands/s "
          f"(target >= {TARGET_CMD_PER_S / 1e6:.0f} M/s: {'met' if rate >= TARGET_CMD_PER_S else 'NOT met'})")
    print(f"  CPU time of that process: {cpu_s:.2f} s -> {lines / cpu_s / 1e6:.2f} M commands per CPU-second "
          "(what an idle machine would approach)")
    print(f"  CLI start-up alone (interpreter + imports of every subcommand, --help): {startup_s:.2f} s wall, "
          f"{startup_cpu_s:.2f} s CPU")
    print(f"same CLI call with imports done (hdeem_watch.cli.main in a warm process): {warm_s:.2f} s wall "
          f"-> {lines / warm_s / 1e6:.2f} M commands/s; {warm_cpu_s:.2f} s CPU -> "
          f"{lines / warm_cpu_s / 1e6:.2f} M commands per CPU-second")
    print(f"peak RSS of the CLI process: {rss / 2**20:.0f} MiB "
          f"(target < 1 GiB: {'met' if rss < TARGET_RSS_BYTES else 'NOT met'})")
    print(f"ratio to DRAMPower v6.2 CLI (0.6 M commands/s, 1.7 GB for 10 M): {rate / DRAMPOWER_CMD_PER_S:.1f}x")
    print(f"core energy {data['core_j']:.6g} J over {data['duration_s'] * 1e3:.3f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
