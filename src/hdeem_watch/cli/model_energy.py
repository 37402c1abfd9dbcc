"""``hdeem-watch model energy``: DRAM energy of a DRAMPower command trace (DESIGN.md section 7).

Usage::

    hdeem-watch model energy --memspec M.json --trace T.csv [--allow-unphysical] [--json]

``--memspec`` takes a DRAMPower JSON memspec file or a preset name (``ddr4-2133-x8-4gb``,
``samsung-m393a1g43db0-cpb``). A file with ``memoryType`` DDR5 selects the DDR5 model
(:mod:`hdeem_watch.dram.energy_ddr5`): the components gain ``refsb_j`` and the counts ``refsb``. The default output is a table; ``--json`` prints one JSON object:
``total_j``, ``core_j``, ``interface_j`` (null: the interface is not modelled, see
``interface_status``), ``components`` (``act_j`` ... ``sref_j``), per-rank ``counts`` (``act, pre,
rd, wr, rda, wra, ref``) and ``cycles`` (``act, pre, pdna, pdnp, sref``) as lists indexed by rank,
and ``ranks`` (per rank: ``rank``, ``core_j``, ``components``, ``counts``, ``cycles``,
``bank_active_cycles``). Bad input
(memspec or trace) is one line on stderr and exit code 2; so is a memspec file whose currents give a
negative per-command energy (:mod:`hdeem_watch.dram.memspec_check`), unless ``--allow-unphysical``
is given (to study a fit's raw output; presets are always physical).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hdeem_watch.dram.presets import PRESETS  # no numpy: the model itself is imported when it runs
from hdeem_watch.dram.stats import COUNT_FIELDS, CYCLE_FIELDS, DDR5_COUNT_FIELDS
from hdeem_watch.errors import InputError

if TYPE_CHECKING:
    from hdeem_watch.dram.energy import EnergyBreakdown
    from hdeem_watch.dram.memspec import MemSpec
    from hdeem_watch.dram.memspec_ddr5 import MemSpecDDR5
    from hdeem_watch.dram.stats import CommandStats


def register(subparsers: Any) -> None:
    """Add ``model energy`` to the ``model`` subcommand's subparsers."""
    parser = subparsers.add_parser(
        "energy", help="DRAM core energy of a DRAMPower command trace (DRAMPower v6 DDR4/DDR5 model)",
        description="Energy of a DRAMPower CSV command trace for a DDR4 or DDR5 memspec (one channel).")
    parser.add_argument("--memspec", required=True, metavar="M.json",
                        help=f"DRAMPower JSON memspec, or a preset (NAME or preset:NAME): "
                             f"{', '.join(sorted(PRESETS))}")
    parser.add_argument("--trace", required=True, metavar="T.csv",
                        help="DRAMPower CLI command trace: cycle,CMD,rank,bankgroup,bank,row,column[,data]")
    add_allow_unphysical(parser)
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    parser.set_defaults(func=run)


def add_allow_unphysical(parser: argparse.ArgumentParser) -> None:
    """The ``--allow-unphysical`` flag of every ``model`` command that takes ``--memspec``."""
    parser.add_argument("--allow-unphysical", action="store_true",
                        help="load a memspec file whose currents give a negative per-command energy (e.g. IDD0 "
                             "below the tRAS/tRC mix of IDD3N and IDD2N) instead of refusing it: for studying a "
                             "fit's raw output")


def resolve_memspec(value: str, *, allow_unphysical: bool = False) -> MemSpec:
    """A memspec file, or a preset by name (``NAME`` when no such file exists, or ``preset:NAME``,
    the spelling RUNS.json uses).

    Args:
        value: the ``--memspec`` argument.
        allow_unphysical: load a file that fails the physical check (``--allow-unphysical``).

    Raises:
        InputError: an unknown preset, a missing file, a malformed memspec, or (without
            ``allow_unphysical``) an unphysical one.
    """
    from hdeem_watch.dram.memspec import memspec_from, preset

    text = str(value)
    name = text.removeprefix("preset:")
    known = ", ".join(sorted(PRESETS))
    if text.startswith("preset:"):
        if name not in PRESETS:
            raise InputError(f"--memspec {text!r}: unknown preset {name!r}; expected one of: {known}")
        return preset(name)
    path = Path(text)
    if path.is_dir():
        raise InputError(f"--memspec {text!r}: is a directory; expected a DRAMPower JSON memspec or a preset")
    if not path.exists() and text not in PRESETS and not (text.endswith(".json") or len(path.parts) > 1):
        raise InputError(f"--memspec {text!r}: no such file and no such preset; expected a DRAMPower JSON "
                         f"memspec or a preset: {known}")
    return memspec_from(text, allow_unphysical=allow_unphysical)


def report(spec: MemSpec | MemSpecDDR5, stats: CommandStats, energy: EnergyBreakdown, *, trace_path: str,
           commands: int, memspec: str) -> dict[str, Any]:
    """The ``--json`` object (pure: no I/O)."""
    count_fields = DDR5_COUNT_FIELDS if spec.memory_type.upper() == "DDR5" else COUNT_FIELDS
    end = stats.ranks[0].cycles_total if stats.ranks else 0.0
    duration_s = end * spec.tck_s
    return {
        "memspec": memspec,
        "memory_id": spec.memory_id,
        "trace": trace_path,
        "commands": commands,
        "end_cycle": end,
        "duration_s": duration_s,
        "total_j": energy.core_j,
        "core_j": energy.core_j,
        "interface_j": None,
        "interface_status": "not modelled (total_j is the core energy)",
        "average_power_w": energy.core_j / duration_s if duration_s > 0 else None,
        "components": dict(energy.components),
        "counts": [{name: getattr(rank, name) for name in count_fields} for rank in stats.ranks],
        "cycles": [{name: getattr(rank, f"cycles_{name}") for name in CYCLE_FIELDS} for rank in stats.ranks],
        "ranks": [{"rank": r, "core_j": sum(parts.values()), "components": parts,
                   "counts": {name: getattr(stats.ranks[r], name) for name in count_fields},
                   "cycles": {name: getattr(stats.ranks[r], f"cycles_{name}") for name in CYCLE_FIELDS},
                   "bank_active_cycles": stats.ranks[r].bank_active_cycles}
                  for r, parts in enumerate(energy.ranks)],
    }


def format_table(data: dict[str, Any], spec: MemSpec | MemSpecDDR5) -> str:
    """The human-readable report."""
    components = list(data["components"])
    count_fields = list(data["counts"][0]) if data["counts"] else list(COUNT_FIELDS)
    lines = [
        f"memspec   {data['memory_id']}",
        f"          {spec.nbr_of_ranks} ranks x {spec.nbr_of_devices} devices, tCK {spec.tck_s * 1e9:g} ns",
        f"trace     {data['trace']}",
        f"          {data['commands']:,} commands, T = {data['end_cycle']:,.0f} cycles "
        f"= {data['duration_s'] * 1e3:.6g} ms",
        "",
        f"{'component':<12}{'energy [J]':>14}{'share':>9}",
    ]
    core = data["core_j"]
    for name in components:
        value = data["components"][name]
        share = f"{100 * value / core:7.2f} %" if core else ""
        lines.append(f"{name.removesuffix('_j'):<12}{value:>14.6e}{share:>9}")
    lines += [f"{'core':<12}{core:>14.6e}", f"{'interface':<12}{'not modelled':>14}",
              f"{'total':<12}{data['total_j']:>14.6e}"]
    if data["average_power_w"] is not None:
        lines.append(f"{'avg power':<12}{data['average_power_w']:>14.6f} W")
    # per rank: the commands, then the cycles in each state (two tables, 80 columns each)
    lines += ["", "commands per rank", "rank " + "".join(f"{n:>10}" for n in count_fields)]
    lines += [f"{r:<5}" + "".join(f"{counts[n]:>10.0f}" for n in count_fields) for r, counts in enumerate(data["counts"])]
    lines += ["", "cycles per rank", "rank " + "".join(f"{n:>13}" for n in CYCLE_FIELDS)]
    lines += [f"{r:<5}" + "".join(f"{cycles[n]:>13.0f}" for n in CYCLE_FIELDS) for r, cycles in enumerate(data["cycles"])]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Compute and print; InputError propagates to the CLI (one line, exit code 2)."""
    from hdeem_watch.dram.command_trace import read_command_trace
    from hdeem_watch.dram.energy import core_energy
    from hdeem_watch.dram.memspec_ddr5 import ddr5_memspec
    from hdeem_watch.dram.trace_state import trace_stats

    ddr5 = ddr5_memspec(args.memspec, allow_unphysical=args.allow_unphysical)
    trace = None
    if ddr5 is not None:
        from hdeem_watch.dram.energy_ddr5 import core_energy_ddr5
        from hdeem_watch.dram.trace_state_ddr5 import trace_stats_ddr5

        spec: MemSpec | MemSpecDDR5 = ddr5
        trace = read_command_trace(args.trace)
        stats = trace_stats_ddr5(ddr5, trace)
        energy = core_energy_ddr5(ddr5, stats)
    else:
        ddr4 = resolve_memspec(args.memspec, allow_unphysical=args.allow_unphysical)
        spec, trace = ddr4, read_command_trace(args.trace)
        stats = trace_stats(ddr4, trace)
        energy = core_energy(ddr4, stats)
    data = report(spec, stats, energy, trace_path=str(args.trace), commands=len(trace), memspec=str(args.memspec))
    if args.json:
        sys.stdout.write(json.dumps(data) + "\n")
    else:
        sys.stdout.write(format_table(data, spec) + "\n")
    return 0
