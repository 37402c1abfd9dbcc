"""``hdeem-watch node``: what this node is (sockets, cores, NUMA, channels, DIMMs), the memspec
chosen for its DIMMs and why, and which DIMMs each power sensor measures.

``--sysfs-root DIR`` reads a sysfs tree other than ``/sys`` (a capture of another node);
``--dmidecode FILE`` reads a saved ``dmidecode -t 17`` print-out (otherwise ``dmidecode -t 17`` is
run when the live node is described and we are root); ``--config FILE`` applies the ``[node]`` table
of a TOML file; ``--json`` prints one JSON object. What could not be detected is listed with the
reason; the exit code is 0 unless the input is bad (2).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from hdeem_watch.errors import InputError


def register(subparsers: Any) -> None:
    """Add the ``node`` subcommand."""
    parser = subparsers.add_parser("node", help="describe this node: topology, DIMMs, memspec, sensor map")
    parser.add_argument("--sysfs-root", type=Path, default=None, metavar="DIR",
                        help="sysfs tree to read (default /sys)")
    parser.add_argument("--dmidecode", type=Path, default=None, metavar="FILE",
                        help="a saved 'dmidecode -t 17' print-out (default: run dmidecode when root)")
    parser.add_argument("--config", type=Path, default=None, metavar="FILE",
                        help="TOML file whose [node] table overrides what is detected")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.set_defaults(func=run)


def _dmidecode_text(args: argparse.Namespace) -> tuple[str | None, str]:
    if args.dmidecode is not None:
        try:
            return args.dmidecode.read_text(encoding="utf-8", errors="replace"), str(args.dmidecode)
        except OSError as error:
            raise InputError(f"--dmidecode {args.dmidecode}: cannot read: {error.strerror or error}") from None
    if args.sysfs_root is not None:
        return None, "not given (--dmidecode FILE; a --sysfs-root capture is not the live node)"
    from hdeem_watch.node.setup import dmidecode_text

    return dmidecode_text()


def _overrides(path: Path | None) -> Any:
    if path is None:
        return None
    from hdeem_watch.config import read_config_file
    from hdeem_watch.node.overrides import parse_node_table, split_node_entry

    table, _name = split_node_entry(read_config_file(path).get("node"))
    return parse_node_table(table or {}, where=f"{path}: [node]")


def _size(size: int | None) -> str:
    return "?" if size is None else f"{size / (1 << 30):g} GiB"


def render(report: dict[str, Any]) -> str:
    """The report as text (what ``hdeem-watch node`` prints without ``--json``)."""
    lines = ["node:"]
    for name, fact in report["facts"].items():
        value = "?" if fact["value"] is None else fact["value"]
        lines.append(f"  {name:<22} {value!s:>4}   {fact['source']}")
    lines.append(f"DIMMs ({len(report['dimms'])}):")
    if report["dimms"]:
        lines.append(f"  {'locator':<18} {'sock':>4} {'ch':>3} {'size':>8} {'type':<5} {'MT/s':>10} {'ranks':>5} "
                     f"{'width':>5}  {'manufacturer':<12} part number")
    for d in report["dimms"]:
        speed = f"{d['speed_mts'] or '?'}/{d['configured_mts'] or '?'}"
        width = f"x{d['device_width']}" if d["device_width"] else (f"{d['total_width']}b" if d["total_width"] else "?")
        socket = "?" if d["socket"] is None else d["socket"]
        channel = d["channel_letter"] or ("?" if d["channel"] is None else d["channel"])
        lines.append(f"  {d['locator']:<18} {socket!s:>4} {channel!s:>3} {_size(d['size_bytes']):>8} "
                     f"{d['type'] or '?':<5} {speed:>10} {d['ranks'] or '?'!s:>5} {width:>5}  "
                     f"{d['manufacturer'] or '?':<12} {d['part_number'] or '?'}")
    memspec = report["memspec"]
    lines.append(f"memspec: {memspec['name'] or '(none)'}  [{memspec['confidence']}]  {memspec['reason']}")
    lines.append("sensors:")
    energy = report.get("dram_energy") or {}
    if not report["sensors"]:
        lines.append("  (none: no DRAM sensor)" if energy.get("model") else "  (none: no DIMM with a known socket)")
    for sensor, locators in report["sensors"].items():
        lines.append(f"  {sensor:<8} {', '.join(locators)}")
    if energy:
        source = energy["sensor"] or (f"none; modelled: {energy['model']}" if energy.get("model") else "none")
        lines.append(f"DRAM energy: {source}  ({energy['how']})")
        if energy.get("currents"):
            lines.append(f"  currents: {energy['currents']}")
    if report["notes"]:
        lines.append("not detected:")
        lines.extend(f"  - {note}" for note in report["notes"])
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """``hdeem-watch node``."""
    from hdeem_watch.node.description import describe_node
    from hdeem_watch.node.overrides import apply_overrides
    from hdeem_watch.node.report import node_report

    root = args.sysfs_root if args.sysfs_root is not None else Path("/sys")
    if args.sysfs_root is not None and not args.sysfs_root.is_dir():
        raise InputError(f"--sysfs-root {args.sysfs_root}: not a directory")
    overrides = _overrides(args.config)
    from hdeem_watch.node.setup import saved_dmidecode

    saved = saved_dmidecode(overrides) if args.dmidecode is None else None
    text, note = saved if saved is not None else _dmidecode_text(args)
    cpuinfo = None
    if args.sysfs_root is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text(encoding="utf-8", errors="replace")
        except OSError:
            cpuinfo = None
    node = describe_node(root, text, note, cpuinfo_text=cpuinfo)
    if overrides is not None:
        node = apply_overrides(node, overrides)
    report = node_report(node, overrides)
    print(json.dumps(report, indent=2) if args.json else render(report), file=sys.stdout)
    return 0
