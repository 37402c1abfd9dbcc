"""``hdeem-watch model stats`` and ``hdeem-watch model kernel``: DRAM command statistics.

Usage::

    hdeem-watch model stats --trace FILE --format ramulator|ramulator2|pinatrace|lackey|drampower
                            --memspec M.json [--mapping SCHEME] [--xor-bank] [--policy open|closed]
                            [--llc-bytes N --llc-ways W] [--emit-drampower OUT.csv] [--allow-unphysical] [--json]
    hdeem-watch model kernel --kernel NAME --elements N --threads T --memspec M.json
                             [--repeat K] [--channels C] [--mapping SCHEME] [--policy P] [--allow-unphysical]
                             [--json]

``stats`` runs a request trace through the controller model (``drampower``: reads a command trace
directly); ``kernel`` models a STREAM-like kernel run. ``--json`` prints one object with
``requests, reads, writes, act, pre, ref, row_hits, row_misses, row_conflicts, cycles`` (totals
over the ranks), ``ranks`` (per-rank statistics), and ``energy`` (``core_j`` and ``components``
from the DRAMPower-equivalent model). Bad input (an empty trace, a count that models nothing): one
line on stderr, exit code 2. Counts take ``bench``'s spellings (``1e6``, ``2**20``:
:mod:`hdeem_watch.cli.numbers`); on a terminal, ``stats`` shows its progress on stderr
(:mod:`hdeem_watch.cli.progress`).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from hdeem_watch.cli.model_energy import add_allow_unphysical
from hdeem_watch.cli.numbers import SPELLINGS, count_at_least
from hdeem_watch.cli.progress import Progress
from hdeem_watch.cli.stats_json import summary
from hdeem_watch.dram.kernels import KERNELS
from hdeem_watch.dram.mapping import SCHEMES
from hdeem_watch.dram.memspec import MemSpec
from hdeem_watch.dram.stats import CommandStats
from hdeem_watch.errors import InputError

STATS_FORMATS = ("ramulator", "ramulator2", "pinatrace", "lackey", "drampower")


def _spec(value: str, allow_unphysical: bool = False) -> MemSpec:
    from hdeem_watch.cli.model_energy import resolve_memspec

    return resolve_memspec(value, allow_unphysical=allow_unphysical)


def register(subparsers: Any) -> None:
    """Add ``model stats`` and ``model kernel`` to the ``model`` subcommand's subparsers."""
    stats = subparsers.add_parser(
        "stats", help="DRAM command statistics of a memory-request trace (the Ramulator step)",
        description="Run a request trace through the vectorised DDR4 controller model.")
    stats.add_argument("--trace", required=True, metavar="FILE", help="request or command trace")
    stats.add_argument("--format", required=True, choices=STATS_FORMATS, help="trace format")
    stats.add_argument("--memspec", required=True, metavar="M.json", help="DRAMPower JSON memspec or preset name")
    _controller_options(stats)
    stats.add_argument("--llc-bytes", type=count_at_least(1, "byte"), default=8 << 20, metavar="N",
                       help="last-level cache in front of pinatrace/lackey traces (default 8 MiB)")
    stats.add_argument("--llc-ways", type=count_at_least(1, "way"), default=16, metavar="W",
                       help="its associativity (default 16)")
    stats.add_argument("--llc-flush", action="store_true", help="write back the dirty lines left at the end")
    stats.add_argument("--emit-drampower", metavar="OUT.csv", help="also write the commands as a DRAMPower trace")
    stats.add_argument("--json", action="store_true", help="print one JSON object")
    stats.set_defaults(func=run_stats)

    kernel = subparsers.add_parser(
        "kernel", help="DRAM command statistics of a STREAM-like kernel run",
        description="Model the DRAM traffic of a kernel (stride 8 doubles, write-allocate) on one channel.")
    kernel.add_argument("--kernel", required=True, metavar="NAME", help=f"one of {', '.join(KERNELS)}")
    kernel.add_argument("--elements", required=True, type=count_at_least(8, "doubles (one 64-byte line)"),
                        metavar="N", help=f"doubles per array, >= 8 ({SPELLINGS})")
    kernel.add_argument("--threads", required=True, type=count_at_least(1, "thread"), metavar="T", help="threads")
    kernel.add_argument("--memspec", required=True, metavar="M.json", help="DRAMPower JSON memspec or preset name")
    kernel.add_argument("--repeat", type=count_at_least(1, "pass"), default=1, metavar="K", help="passes (default 1)")
    kernel.add_argument("--channels", type=count_at_least(1, "channel"), default=1, metavar="C",
                        help="channels sharing the traffic; statistics are for one of them (default 1)")
    _controller_options(kernel)
    kernel.add_argument("--json", action="store_true", help="print one JSON object")
    kernel.set_defaults(func=run_kernel)


def _controller_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--mapping", default="RoBaRaCoCh", metavar="SCHEME",
                        help=f"address mapping, MSB to LSB (default RoBaRaCoCh; e.g. {', '.join(SCHEMES)})")
    parser.add_argument("--xor-bank", action="store_true", help="XOR bank hashing")
    parser.add_argument("--policy", choices=("open", "closed"), default="open", help="row-buffer policy")
    add_allow_unphysical(parser)


def _energy(spec: MemSpec, stats: CommandStats) -> dict[str, Any] | None:
    try:
        from hdeem_watch.dram.energy import core_energy
    except ImportError:  # pragma: no cover - the energy model ships with the package
        return None
    energy = core_energy(spec, stats)
    return {"core_j": energy.core_j, "components": dict(energy.components)}


def _print(data: dict[str, Any], as_json: bool) -> None:
    if as_json:
        sys.stdout.write(json.dumps(data) + "\n")
        return
    lines = []
    for key in ("trace", "kernel", "requests", "reads", "writes", "act", "pre", "ref", "refsb", "row_hits",
                "row_misses", "row_conflicts", "cycles"):
        if key in data and data[key] is not None:
            value = data[key]
            lines.append(f"{key:<14}{value:>16,.0f}" if isinstance(value, int | float) else f"{key:<14}{value:>16}")
    if data.get("energy"):
        lines.append(f"{'core energy':<14}{data['energy']['core_j']:>16.6e} J")
    per_sub = len(data["subchannels"][0]["ranks"]) if isinstance(data.get("subchannels"), list) else 0
    for r, rank in enumerate(data["ranks"]):
        label = f"sub-channel {r // per_sub} rank {r % per_sub}" if per_sub else f"rank {r}"
        lines.append(f"{label}: act {rank['act']:.0f} pre {rank['pre']:.0f} rd {rank['rd'] + rank['rda']:.0f} "
                     f"wr {rank['wr'] + rank['wra']:.0f} ref {rank['ref']:.0f} cycles act/pre "
                     f"{rank['cycles_act']:.0f}/{rank['cycles_pre']:.0f}")
    sys.stdout.write("\n".join(lines) + "\n")


def run_stats(args: argparse.Namespace) -> int:
    """``model stats``."""
    from hdeem_watch.dram.memspec_ddr5 import ddr5_memspec

    ddr5 = ddr5_memspec(args.memspec, allow_unphysical=args.allow_unphysical)
    if ddr5 is not None:  # DDR5: both sub-channels (cli/model_stats_ddr5.py)
        from hdeem_watch.cli.model_stats_ddr5 import trace_ddr5

        progress = Progress(sys.stderr)
        try:
            data = trace_ddr5(ddr5, args, progress.callback())
        finally:
            progress.clear()
        data["trace"] = str(args.trace)
        _print(data, args.json)
        return 0
    spec = _spec(args.memspec, args.allow_unphysical)
    progress = Progress(sys.stderr)
    try:
        data, stats = _trace_summary(spec, args, progress)
    finally:
        progress.clear()
    data["trace"] = str(args.trace)
    data["energy"] = _energy(spec, stats)
    _print(data, args.json)
    return 0


def _trace_summary(spec: MemSpec, args: argparse.Namespace, progress: Progress) -> tuple[dict[str, Any], CommandStats]:
    """The ``--json`` object (without trace and energy) and the statistics of ``args.trace``.

    Raises:
        InputError: a bad trace, an empty one, or an unwritable ``--emit-drampower`` file.
    """
    if args.format == "drampower":
        if args.emit_drampower:
            raise InputError("--emit-drampower: the input already is a DRAMPower trace")
        from hdeem_watch.dram.command_trace import read_command_trace
        from hdeem_watch.dram.trace_state import trace_stats

        trace = read_command_trace(args.trace)
        stats = trace_stats(spec, trace)
        rd, wr = stats.total("rd") + stats.total("rda"), stats.total("wr") + stats.total("wra")
        data = summary(stats, requests=rd + wr, reads=rd, writes=wr, row_hits=None, row_misses=None,
                       row_conflicts=None, cycles=stats.ranks[0].cycles_total if stats.ranks else 0.0)
        return data, stats
    from hdeem_watch.dram.request_traces import CacheConfig
    from hdeem_watch.dram.trace_simulation import simulate_trace

    cache = CacheConfig(size_bytes=args.llc_bytes, ways=args.llc_ways, flush=args.llc_flush)
    result, cpu_accesses = simulate_trace(spec, args.trace, args.format, cache=cache, policy=args.policy,
                                          mapping=args.mapping, xor_bank=args.xor_bank,
                                          keep_commands=bool(args.emit_drampower), progress=progress.callback())
    if result.requests == 0:
        found = f" ({cpu_accesses} CPU accesses, all served by the cache)" if cpu_accesses else ""
        raise InputError(f"{args.trace}: no memory requests in the trace{found}; expected {args.format} lines")
    data = summary(result.stats, requests=result.requests, reads=result.reads, writes=result.writes,
                   row_hits=result.row_hits, row_misses=result.row_misses,
                   row_conflicts=result.row_conflicts, cycles=result.cycles)
    if cpu_accesses:
        data["cpu_accesses"] = cpu_accesses
    if args.emit_drampower:
        from hdeem_watch.dram.command_emit import write_drampower_trace

        try:
            data["drampower_commands"] = write_drampower_trace(Path(args.emit_drampower), result,
                                                               progress=progress.callback())
        except OSError as error:
            raise InputError(f"--emit-drampower {args.emit_drampower}: {error.strerror}") from None
        data["drampower_trace"] = str(args.emit_drampower)
    return data, result.stats


def run_kernel(args: argparse.Namespace) -> int:
    """``model kernel``."""
    from hdeem_watch.dram.kernels import canonical_kernel, kernel_stats
    from hdeem_watch.dram.memspec_ddr5 import ddr5_memspec

    ddr5 = ddr5_memspec(args.memspec, allow_unphysical=args.allow_unphysical)
    name = canonical_kernel(args.kernel)
    if ddr5 is not None:  # DDR5: one 32-bit sub-channel (cli/model_stats_ddr5.py)
        from hdeem_watch.cli.model_stats_ddr5 import kernel_ddr5

        _print(kernel_ddr5(ddr5, name, args), args.json)
        return 0
    spec = _spec(args.memspec, args.allow_unphysical)
    model = kernel_stats(spec, name, args.elements, args.threads, repeat=args.repeat, channels=args.channels,
                         mapping=args.mapping, policy=args.policy, xor_bank=args.xor_bank)
    data = summary(model.stats, requests=model.reads + model.writes, reads=model.reads, writes=model.writes,
                   row_hits=model.row_hits, row_misses=model.row_misses, row_conflicts=model.row_conflicts,
                   cycles=model.cycles)
    data.update(kernel=name, elements=args.elements, threads=args.threads, repeat=args.repeat,
                channels=args.channels, seconds=model.cycles * spec.tck_s, prefix_scale=model.scale)
    data["energy"] = _energy(spec, model.stats)
    _print(data, args.json)
    return 0
