"""``model stats`` and ``model kernel`` on a DDR5 memspec (dispatched from :mod:`hdeem_watch.cli.model_stats`).

The memspec describes one 32-bit sub-channel (:mod:`hdeem_watch.dram.ddr5_channel`). ``kernel``
prints the statistics of one of the ``2 × channels`` sub-channels (as DDR4's prints one of
``channels`` channels); ``stats`` serves a DIMM's request trace on both sub-channels and prints the
totals over both, the per-rank statistics of each (``subchannels``: a list of two summaries) and
the energy summed over both. ``--format drampower`` reads a command trace of one sub-channel.
"""

from __future__ import annotations

import argparse
from typing import Any

from hdeem_watch.dram.memspec_ddr5 import MemSpecDDR5
from hdeem_watch.dram.stats import CommandStats


def energy_ddr5(spec: MemSpecDDR5, stats: CommandStats) -> dict[str, Any]:
    """The ``energy`` object of the JSON (``core_j``, ``components`` incl. ``refsb_j``)."""
    from hdeem_watch.dram.energy_ddr5 import core_energy_ddr5

    energy = core_energy_ddr5(spec, stats)
    return {"core_j": energy.core_j, "components": dict(energy.components)}


def kernel_ddr5(spec: MemSpecDDR5, name: str, args: argparse.Namespace) -> dict[str, Any]:
    """The ``--json`` object of ``model kernel`` on a DDR5 memspec."""
    from hdeem_watch.cli.stats_json import summary
    from hdeem_watch.dram.ddr5_channel import SUBCHANNELS, kernel_stats_ddr5

    model = kernel_stats_ddr5(spec, name, args.elements, args.threads, repeat=args.repeat, channels=args.channels,
                              mapping=args.mapping, policy=args.policy, xor_bank=args.xor_bank)
    data = summary(model.stats, requests=model.reads + model.writes, reads=model.reads, writes=model.writes,
                   row_hits=model.row_hits, row_misses=model.row_misses, row_conflicts=model.row_conflicts,
                   cycles=model.cycles)
    data.update(kernel=name, elements=args.elements, threads=args.threads, repeat=args.repeat,
                channels=args.channels, subchannels=SUBCHANNELS * args.channels, refsb=model.stats.total("refsb"),
                seconds=model.cycles * spec.tck_s, prefix_scale=model.scale)
    data["energy"] = energy_ddr5(spec, model.stats)
    return data


def trace_ddr5(spec: MemSpecDDR5, args: argparse.Namespace, callback: Any) -> dict[str, Any]:
    """The ``--json`` object of ``model stats`` on a DDR5 memspec.

    Raises:
        InputError: a bad or empty trace, or ``--emit-drampower`` (not available for DDR5).
    """
    from hdeem_watch.cli.stats_json import summary
    from hdeem_watch.errors import InputError

    if args.emit_drampower:
        raise InputError("--emit-drampower: not available for a DDR5 memspec (the DDR5 command trace writer "
                         "is not built); drop the option")
    if args.format == "drampower":
        from hdeem_watch.dram.command_trace import read_command_trace
        from hdeem_watch.dram.trace_state_ddr5 import trace_stats_ddr5

        stats = trace_stats_ddr5(spec, read_command_trace(args.trace))
        rd, wr = stats.total("rd") + stats.total("rda"), stats.total("wr") + stats.total("wra")
        data = summary(stats, requests=rd + wr, reads=rd, writes=wr, row_hits=None, row_misses=None,
                       row_conflicts=None, cycles=stats.ranks[0].cycles_total if stats.ranks else 0.0)
        data.update(refsb=stats.total("refsb"), energy=energy_ddr5(spec, stats))
        return data
    return _both_subchannels(spec, args, callback, summary)


def _both_subchannels(spec: MemSpecDDR5, args: argparse.Namespace, callback: Any, summary: Any) -> dict[str, Any]:
    """A request trace served on sub-channel 0 and sub-channel 1; totals and energy over both."""
    from hdeem_watch.dram.ddr5_channel import SUBCHANNELS, subchannel_spec
    from hdeem_watch.dram.request_traces import CacheConfig
    from hdeem_watch.dram.trace_simulation import simulate_trace
    from hdeem_watch.errors import InputError

    sub = subchannel_spec(spec)
    cache = CacheConfig(size_bytes=args.llc_bytes, ways=args.llc_ways, flush=args.llc_flush)
    parts, cpu_accesses = [], 0
    for channel in range(SUBCHANNELS):
        result, cpu_accesses = simulate_trace(sub, args.trace, args.format, cache=cache, policy=args.policy,
                                              mapping=args.mapping, xor_bank=args.xor_bank, channel=channel,
                                              progress=callback)
        parts.append(result)
    if sum(p.requests for p in parts) == 0:
        found = f" ({cpu_accesses} CPU accesses, all served by the cache)" if cpu_accesses else ""
        raise InputError(f"{args.trace}: no memory requests in the trace{found}; expected {args.format} lines")
    each = [summary(p.stats, requests=p.requests, reads=p.reads, writes=p.writes, row_hits=p.row_hits,
                    row_misses=p.row_misses, row_conflicts=p.row_conflicts, cycles=p.cycles) for p in parts]
    energies = [energy_ddr5(spec, p.stats) for p in parts]
    for one, energy in zip(each, energies, strict=True):
        one["energy"] = energy
    data: dict[str, Any] = {key: sum(one[key] for one in each) for key in
                            ("requests", "reads", "writes", "act", "pre", "ref", "rd", "wr", "row_hits",
                             "row_misses", "row_conflicts")}
    data["refsb"] = sum(p.stats.total("refsb") for p in parts)
    data["cycles"] = max(p.cycles for p in parts)
    data["ranks"] = [rank for one in each for rank in one["ranks"]]  # sub-channel 0's ranks, then 1's
    data["subchannels"] = each
    components = {name: sum(e["components"][name] for e in energies) for name in energies[0]["components"]}
    data["energy"] = {"core_j": sum(e["core_j"] for e in energies), "components": components}
    if cpu_accesses:
        data["cpu_accesses"] = cpu_accesses
    return data
