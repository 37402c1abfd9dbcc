"""``hdeem-watch run list|stop``: the runs a daemon holds, and ending the one in progress.

``run list`` prints the daemon's newest runs (``runs.list``): id, name, state, length, DRAM energy
and whether the calibration took it. ``run stop`` stops the run in progress (or ``--run ID``);
``--abort`` stores it without calibrating with it, e.g. a benchmark that was killed before it could
say so. Stopping needs the same rights as starting (root, the daemon's user, or the owner of a job
running on the node).

Exit codes: 0 done, 1 the daemon did not answer or refused (or no run is in progress), 2 bad input.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Mapping
from datetime import datetime
from typing import Any

from hdeem_watch.cli.daemon_client import Failed, add_connect_arguments, open_client, reported
from hdeem_watch.run_record import RunRecord

EPILOG = """examples:
  hdeem-watch run list                      # this node's daemon: its newest runs
  hdeem-watch run stop --abort              # end the run, not calibrating
  hdeem-watch run stop --run r53 --connect tcp://node7:5591
exit codes: 0 done, 1 no reply, refused, or no run in progress, 2 bad input"""


def register(subparsers: Any) -> None:
    """Add the ``run`` subcommand."""
    parser = subparsers.add_parser(
        "run", help="list a daemon's runs, or stop (abort) the one in progress",
        description="List a running daemon's runs, or stop the run in progress.", epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    actions = parser.add_subparsers(dest="action", metavar="ACTION", parser_class=type(parser))
    listing = actions.add_parser("list", help="the newest runs", description="The daemon's newest runs.")
    listing.add_argument("--limit", type=int, default=20, help="how many runs (1..1000, default 20)")
    listing.add_argument("--kernel", metavar="K", help="only runs of this kernel")
    listing.add_argument("--json", action="store_true", help="print the runs.list reply as JSON")
    add_connect_arguments(listing)
    listing.set_defaults(func=_list)
    stop = actions.add_parser("stop", help="stop the run in progress (or --run ID)",
                              description="Stop the run in progress, or the one named by --run.")
    stop.add_argument("--run", metavar="ID", help="the run to stop (default: the one in progress)")
    stop.add_argument("--abort", action="store_true", help="store the run but do not calibrate with it")
    stop.add_argument("--json", action="store_true", help="print the stopped run's record as JSON")
    add_connect_arguments(stop)
    stop.set_defaults(func=_stop)
    parser.set_defaults(func=lambda _args: (parser.print_help(sys.stderr), 2)[1])


def _list(args: argparse.Namespace) -> int:
    request: dict[str, Any] = {"limit": args.limit}
    if args.kernel:
        request["kernel"] = args.kernel
    with reported("run list"), open_client(args) as client:
        runs = client.call("runs.list", request).get("runs") or []
    if args.json:
        print(json.dumps({"runs": runs}))
    else:
        print(format_runs(runs))
    return 0


def format_runs(runs: list[Mapping[str, Any]]) -> str:
    """The ``run list`` table (80 columns), newest first; "no runs yet" when there are none. Each
    entry is read by the one parser of run records (one that is none is a line saying so).

    Example:
        >>> print(format_runs([{"run_id": "r2", "name": "triad-1t", "state": "done", "window_s": 2.01,
        ...     "dram_energy_j": 61.2, "t_start_ns": 0, "fit": {"n_runs": 1}}]))  # doctest: +ELLIPSIS
        run   name                  state       seconds   DRAM J  started   calibrated
        r2    triad-1t              done          2.010    61.20  ...  yes
    """
    if not runs:
        return "no runs yet"
    lines = [f"{'run':<6}{'name':<22}{'state':<10}{'seconds':>9}{'DRAM J':>9}  {'started':<10}calibrated"]
    for entry in runs:
        try:
            run = RunRecord.from_dict(entry)
        except ValueError as error:
            lines.append(f"unreadable run entry: {error}")
            continue
        lines.append(f"{run.run_id:<6}{run.name[:21]:<22}{run.state:<10}"
                     f"{_number(run.window_s, 3):>9}{_number(run.dram_energy_j, 2):>9}  "
                     f"{_clock(run.t_start_ns):<10}{_calibrated(run)}")
    return "\n".join(lines)


def _number(value: float | None, digits: int) -> str:
    return f"{value:.{digits}f}" if value is not None and math.isfinite(value) else "–"


def _clock(t_ns: int | None) -> str:
    return datetime.fromtimestamp(t_ns / 1e9).strftime("%H:%M:%S") if t_ns is not None else "–"


def _calibrated(run: RunRecord) -> str:
    if run.state == "done":
        return "yes" if run.fit else "no (run list --json: model_error)"
    return {"aborted": "no (aborted)", "running": "–", "modelling": "…"}.get(run.state, "–")


def _stop(args: argparse.Namespace) -> int:
    with reported("run stop"), open_client(args) as client:
        run_id = args.run
        if run_id is None:
            running = client.call("status").get("run")
            if not isinstance(running, Mapping):
                raise Failed("no run is in progress on this daemon (run list shows the finished ones)")
            run_id = running.get("run_id")
        record = client.call("run.stop", {"run_id": run_id, "abort": bool(args.abort)})
        if args.json:
            print(json.dumps(record))
            return 0
        try:
            run = RunRecord.from_dict(record)
        except ValueError as error:
            raise Failed(f"the daemon's run.stop reply is {error}") from None
    how = "aborted (stored, not calibrated)" if run.state == "aborted" else "stopped"
    print(f"run {run.run_id} ({run.name}) {how}: {_number(run.window_s, 3)} s, "
          f"DRAM {_number(run.dram_energy_j, 2)} J")
    return 0
