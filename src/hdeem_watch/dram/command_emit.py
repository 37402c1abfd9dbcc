"""Write the controller model's commands as a DRAMPower command trace.

Format (DRAMPower CLI CSV, no header): ``cycle,CMD,rank,bankgroup,bank,row,column``, ``bank``
flat in the rank, columns in device columns (burst index × BL). Each refresh is a PREA followed
``tRP`` later by a REFA on every rank; the last line is ``END`` at the evaluation time. The
statistics :func:`hdeem_watch.dram.controller.simulate` returns are computed from exactly these
commands, so DRAMPower (or :func:`hdeem_watch.dram.trace_state.trace_stats`) on this file gives
the same energy.

Example:
    >>> from hdeem_watch.dram.memspec import preset
    >>> from hdeem_watch.dram.kernels import kernel_requests
    >>> from hdeem_watch.dram.controller import simulate
    >>> result = simulate(preset("ddr4-2133-x8-4gb"), *kernel_requests("read", 64), keep_commands=True)
    >>> drampower_lines(result)[:2]
    ['0,ACT,0,0,0,4096,0', '15,RD,0,0,0,4096,0']
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from hdeem_watch.dram.command_set import ControllerResult
from hdeem_watch.dram.progress import ProgressCallback

#: The phase :func:`write_drampower_trace` reports progress under.
PROGRESS_PHASE = "writing DRAMPower trace"
_NAMES = ("PREA", "PRE", "REFA", "ACT", "RD", "WR", "RDA", "WRA")
_PREA, _PRE, _REFA, _ACT, _RD, _WR, _RDA, _WRA = range(len(_NAMES))


def _columns(result: ControllerResult) -> tuple[np.ndarray, ...]:
    """Every command as parallel arrays (cycle, kind, rank, bankgroup, bank, row, column), time-ordered."""
    commands = result.commands
    if commands is None:
        raise ValueError("the result holds no commands: simulate(..., keep_commands=True)")
    geometry = result.geometry
    per_group = geometry.banks_per_group
    ranks = np.arange(geometry.ranks, dtype=np.int64)
    ref = commands.ref_cycle
    n_ref = ref.size
    prea_cycle = np.repeat(ref, geometry.ranks)
    prea_rank = np.tile(ranks, n_ref)
    col_kind = np.where(commands.col_write, np.where(commands.col_auto, _WRA, _WR),
                        np.where(commands.col_auto, _RDA, _RD))
    cycle = np.concatenate((prea_cycle, prea_cycle + int(commands.refa_delay), commands.pre_cycle,
                            commands.act_cycle, commands.col_cycle))
    kind = np.concatenate((np.full(prea_cycle.size, _PREA), np.full(prea_cycle.size, _REFA),
                           np.full(commands.pre_cycle.size, _PRE), np.full(commands.act_cycle.size, _ACT),
                           col_kind))
    zeros = np.zeros(prea_cycle.size, dtype=np.int64)
    rank = np.concatenate((prea_rank, prea_rank, commands.pre_rank, commands.act_rank, commands.col_rank))
    bank = np.concatenate((zeros, zeros, commands.pre_bank, commands.act_bank, commands.col_bank))
    row = np.concatenate((zeros, zeros, np.zeros(commands.pre_cycle.size, dtype=np.int64), commands.act_row,
                          commands.col_row))
    column = np.concatenate((zeros, zeros, np.zeros(commands.pre_cycle.size + commands.act_cycle.size, dtype=np.int64),
                             commands.col_column * geometry.burst_length))
    order = np.lexsort((kind, cycle))
    bank = bank[order]
    return cycle[order], kind[order], rank[order], bank // per_group, bank, row[order], column[order]


def iter_drampower_lines(result: ControllerResult, chunk: int = 1 << 18) -> Iterator[str]:
    """The trace lines, without newlines, in time order, ``END`` last."""
    end_cycle = result.commands.end_cycle if result.commands is not None else 0
    cycle, kind, rank, bankgroup, bank, row, column = _columns(result)
    for start in range(0, cycle.size, chunk):
        stop = start + chunk
        names = np.array(_NAMES)[kind[start:stop]].tolist()
        yield from (f"{c},{k},{r},{g},{b},{w},{o}" for c, k, r, g, b, w, o in zip(
            cycle[start:stop].tolist(), names, rank[start:stop].tolist(), bankgroup[start:stop].tolist(),
            bank[start:stop].tolist(), row[start:stop].tolist(), column[start:stop].tolist()))
    yield f"{end_cycle},END,0,0,0,0,0"


def drampower_lines(result: ControllerResult) -> list[str]:
    """All trace lines (small results only)."""
    return list(iter_drampower_lines(result))


def command_count(result: ControllerResult) -> int:
    """Lines :func:`write_drampower_trace` writes for ``result`` (END included)."""
    commands = result.commands
    if commands is None:
        raise ValueError("the result holds no commands: simulate(..., keep_commands=True)")
    refreshes = 2 * commands.ref_cycle.size * result.geometry.ranks  # PREA + REFA per rank
    return refreshes + commands.pre_cycle.size + commands.act_cycle.size + commands.col_cycle.size + 1


def write_drampower_trace(path: str | Path, result: ControllerResult, *,
                          progress: ProgressCallback | None = None) -> int:
    """Write the trace to ``path``; return the number of commands written (END included).

    ``progress("writing DRAMPower trace", lines_written, lines_total)`` is called after each batch
    of lines.
    """
    total = command_count(result)
    count = 0
    with open(path, "w", encoding="ascii") as handle:
        batch: list[str] = []
        for line in iter_drampower_lines(result):
            batch.append(line)
            if len(batch) >= 65536:
                handle.write("\n".join(batch) + "\n")
                count += len(batch)
                batch = []
                if progress is not None:
                    progress(PROGRESS_PHASE, count, total)
        handle.write("\n".join(batch) + "\n")
        count += len(batch)
    if progress is not None:
        progress(PROGRESS_PHASE, count, total)
    return count
