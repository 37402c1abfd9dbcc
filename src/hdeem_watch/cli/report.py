"""``hdeem-watch report``: the paper's figures from a daemon's state or a RUNS.json (docs/report.md).

``hdeem-watch report [--state-dir DIR | --runs RUNS.json] [--since T] [--group G] [--out DIR]
[--format html|png|svg|pdf]`` writes ``DIR/index.html`` (self-contained: figures embedded, no
network needed), the figures as files in the chosen format (none for ``html``), ``numbers.json`` and
``memspec-calibrated.json``. Needs matplotlib (``pip install hdeem-watch[report]``); without it the
command says so in one line and exits 2.
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

EXIT_MISSING_EXTRA = 1


def register(subparsers: Any) -> None:
    """Add the ``report`` subcommand."""
    parser = subparsers.add_parser(
        "report", help="figures and an HTML page from a daemon state or a RUNS.json",
        description="Draw the paper's figures for this node — measured vs datasheet vs calibrated energy, "
                    "currents with intervals, residuals, aging, energy by component, jobs — into a "
                    "self-contained HTML page plus the figure files.")
    source = parser.add_mutually_exclusive_group()
    source.add_argument("--state-dir", metavar="DIR",
                        help="the daemon's state directory (default: the daemon's default state directory)")
    source.add_argument("--runs", metavar="RUNS.json", help="a calibration input instead of a daemon state")
    parser.add_argument("--since", metavar="T", help="only runs and fits from T on: an age (12h, 7d) or an "
                                                     "ISO date/time (UTC unless it has an offset)")
    parser.add_argument("--group", metavar="G", help="the DIMM pair (e.g. DDR_CD) for the per-pair figures "
                                                     "(default node: all pairs)")
    parser.add_argument("--out", default="hdeem-watch-report", metavar="DIR",
                        help="output directory (default ./hdeem-watch-report)")
    parser.add_argument("--format", default="png", choices=("html", "png", "svg", "pdf"),
                        help="format of the figure files beside index.html (html = the page only; default png)")
    parser.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from hdeem_watch.report.build import write_report
    from hdeem_watch.report.style import MissingPlotting, pyplot

    try:
        pyplot()
    except MissingPlotting:
        print("hdeem-watch report: error: matplotlib is not installed; pip install 'hdeem-watch[report]'", file=sys.stderr)
        return EXIT_MISSING_EXTRA
    started = time.monotonic()
    written = write_report(state_dir=args.state_dir, runs=args.runs, since=args.since, group=args.group,
                           out=args.out, fmt=args.format)
    print(f"report: {written.page} ({len(written.figures)} figure files, {time.monotonic() - started:.1f} s)")
    for key, missing in written.missing.items():
        for what in missing:
            print(f"report: {key}: no data: {what}")
    for key, notes in written.notes.items():
        for note in notes:
            print(f"report: {key}: note: {note}")
    return 0
