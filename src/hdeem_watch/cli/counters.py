"""``hdeem-watch counters``: the memory-controller PMUs, channels and events this host would use.

Usage::

    hdeem-watch counters [--sysfs-root DIR] [--cpuinfo FILE] [--proc-root DIR] [--ranks N] [--json]

Prints the CPU generation and its event sources, the ``uncore_imc_*`` PMUs (type, cpumask, format
fields), the channels (socket × box) and the encoded events — or why this host cannot count (no
uncore PMU, e.g. in a virtual machine; an unknown CPU; permissions, with ``perf_event_paranoid`` and
``CAP_PERFMON`` explained). Both are a successful answer: exit code 0. A malformed sysfs tree or
cpuinfo is bad input: one line on stderr, exit code 2. See docs/counters.md.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from hdeem_watch.counters.cpu_identity import DEFAULT_CPUINFO
from hdeem_watch.counters.event_tables import PERF_JSON_COMMIT, PERFMON_COMMIT
from hdeem_watch.counters.host_plan import HostPlan, plan_host
from hdeem_watch.counters.permissions import probe_access
from hdeem_watch.counters.pmu_discovery import DEFAULT_SYSFS_ROOT
from hdeem_watch.errors import InputError


def register(subparsers: Any) -> None:
    """Add ``counters``."""
    parser = subparsers.add_parser(
        "counters", help="memory-controller counters: PMUs, channels and events this host would use",
        description="List the uncore IMC PMUs, channels and DRAM-command events this host would count, "
                    "or explain why it cannot (no uncore PMU, unknown CPU, permissions).")
    parser.add_argument("--sysfs-root", default=DEFAULT_SYSFS_ROOT, metavar="DIR",
                        help="directory holding bus/event_source/devices (default: /sys)")
    parser.add_argument("--cpuinfo", default=DEFAULT_CPUINFO, metavar="FILE",
                        help="cpuinfo file giving the CPU generation (default: /proc/cpuinfo)")
    parser.add_argument("--proc-root", default="/proc", metavar="DIR",
                        help="proc directory for sys/kernel/perf_event_paranoid and self/status (default: /proc)")
    parser.add_argument("--ranks", type=int, default=2, metavar="N",
                        help="ranks per channel: CKE residency is counted for ranks 0..N-1 (default: 2, "
                             "as the DIMM presets)")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Plan the host and print it; 0 whether or not it can count."""
    given_roots = (("--sysfs-root", args.sysfs_root, DEFAULT_SYSFS_ROOT), ("--proc-root", args.proc_root, "/proc"))
    for flag, given, default in given_roots:
        if str(given) != str(default) and not Path(given).is_dir():
            raise InputError(f"{flag} {given}: not a directory")  # like `node`: a typo, not a host without PMUs
    proc = Path(args.proc_root)
    access = probe_access(proc / "sys/kernel/perf_event_paranoid", proc / "self/status")
    plan = plan_host(sysfs_root=args.sysfs_root, cpuinfo_path=args.cpuinfo, access=access, ranks=args.ranks)
    if args.json:
        print(json.dumps({**plan.to_dict(), "perfmon_commit": PERFMON_COMMIT, "perf_json_commit": PERF_JSON_COMMIT},
                         indent=2))
    else:
        print(render_text(plan))
    return 0


def render_text(plan: HostPlan) -> str:
    """The human-readable report (pure)."""
    lines = []
    cpu = plan.cpu
    if cpu is not None:
        title = plan.table.title if plan.table is not None else "no event table"
        lines.append(f"CPU: {cpu.signature()} stepping {cpu.stepping} ({cpu.model_name or 'unnamed'}) -> {title}")
    if plan.table is not None:
        origin = (f"linux@{PERF_JSON_COMMIT[:12]} " if plan.table.pmu_prefix == "amd_umc"
                  else f"intel/perfmon@{PERFMON_COMMIT[:12]} ")
        lines.append("event sources: " + origin + "; ".join(plan.table.sources))
    lines.append(f"memory-controller PMUs: {len(plan.pmus)}" + ("" if plan.pmus else " (none)"))
    for pmu in plan.pmus:
        formats = " ".join(f"{name}={field.describe()}" for name, field in sorted(pmu.formats.items()))
        kind = " free-running (not used)" if pmu.free_running else ""
        lines.append(f"  {pmu.name:<28} type {pmu.pmu_type:<4} cpumask {','.join(map(str, pmu.cpus)):<8} "
                     f"{formats}{kind}")
    if plan.channels:
        lines.append(f"channels: {len(plan.channels)}")
        lines.extend(f"  {c.name:<10} {c.pmu:<16} type {c.pmu_type:<4} cpu {c.cpu}" for c in plan.channels)
    if plan.events:
        lines.append(f"events per channel: {len(plan.events)}")
        for e in plan.events:
            flag = " (experimental)" if e.experimental else ""
            alias = f" = perf {e.perf_alias}" if e.perf_alias else ""
            lines.append(f"  {e.role:<16} {e.name:<36} event {e.event:#04x} {e.mask_field} {e.umask:#04x} "
                         f"config {e.config:#x}{flag}{alias}")
    lines.append(f"permissions: {plan.access.explanation}")
    lines.extend(f"note: {note}" for note in plan.notes)
    if plan.usable:
        lines.append("status: ready to count")
    else:
        lines.append("status: cannot count on this host")
        lines.extend(f"  - {reason}" for reason in plan.reasons)
    return "\n".join(lines)
