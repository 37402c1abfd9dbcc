"""``hdeem-watch tui``: the live terminal UI for one or more node daemons.

``--connect ENDPOINT`` (repeatable) names a daemon's *control* endpoint; the UI asks it for the
stream endpoint. Without it the UI connects to the local daemon's default endpoint. ``--slurm``
connects to every node of the current SLURM allocation at ``tcp://<node>:<port>`` (port
:data:`SLURM_CONTROL_PORT` unless ``--port`` or ``$HDEEM_WATCH_CONTROL_PORT`` says otherwise; the
daemons must listen there, e.g. ``--control tcp://*:5591``).
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import Any, TextIO

from hdeem_watch.errors import InputError

#: Documented TCP port of a daemon's control endpoint on cluster nodes (``--slurm``).
SLURM_CONTROL_PORT = 5591
PORT_ENV = "HDEEM_WATCH_CONTROL_PORT"
ENDPOINT_SCHEMES = ("ipc://", "tcp://", "inproc://")


def register(subparsers: Any) -> None:
    """Add the ``tui`` subcommand."""
    parser = subparsers.add_parser(
        "tui",
        help="live terminal UI: power per DIMM pair, baselines, runs, calibration",
        description="Live terminal UI of one or more hdeem-watch daemons (keys: p pause, n node, "
        "+/- zoom, b baseline, s stop run, ? help, q quit).",
        epilog="examples:\n"
        "  hdeem-watch tui                                      # the local daemon\n"
        f"  hdeem-watch tui --connect tcp://node7:{SLURM_CONTROL_PORT} --fps 2   # a remote node over slow ssh\n"
        "  hdeem-watch tui --slurm                              # every node of the allocation\n"
        "  hdeem-watch tui --headless --duration 60             # text lines for 60 s\n"
        "exit codes: 0 done, 1 a daemon never sent its stream (--headless; the reason on stderr),\n"
        "  2 bad input, 130 interrupted (--headless)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--connect",
        metavar="ENDPOINT",
        action="append",
        default=[],
        help="a daemon's control endpoint (repeatable); default: the local daemon",
    )
    parser.add_argument("--slurm", action="store_true", help="connect to every node of the SLURM allocation")
    parser.add_argument(
        "--port",
        type=int,
        default=None,
        help=f"control port of the daemons for --slurm (default ${PORT_ENV} or {SLURM_CONTROL_PORT})",
    )
    parser.add_argument("--fps", type=float, default=10.0, help="frames per second (default 10; lower it over slow ssh)")
    parser.add_argument("--window", type=float, default=60.0, metavar="S",
                        help="initial plot window in seconds (default 60; +/- zoom 5..600)")
    parser.add_argument(
        "--headless", action="store_true", help="print runs, calibration and power as text lines instead of the UI"
    )
    parser.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds (default: until q or Ctrl-C)")
    parser.add_argument(
        "--stats", metavar="FILE", default=None, help="append frames/CPU/messages each second as JSON lines (benchmarks)"
    )
    parser.set_defaults(func=_run)


def check_endpoint(endpoint: str) -> str:
    """Validate an endpoint given on the command line.

    Raises:
        InputError: when it has no ZeroMQ transport prefix.
    """
    if not endpoint.startswith(ENDPOINT_SCHEMES):
        raise InputError(f"--connect {endpoint!r}: expected a ZeroMQ endpoint such as tcp://node7:{SLURM_CONTROL_PORT} or ipc:///path")
    return endpoint


def slurm_endpoints(port: int | None = None, env: dict[str, str] | None = None) -> list[str]:
    """Control endpoints of every node of the allocation.

    Raises:
        InputError: outside an allocation, or for a bad port.
    """
    from hdeem_watch import slurm

    environ = dict(os.environ if env is None else env)
    if port is None:
        raw = environ.get(PORT_ENV, str(SLURM_CONTROL_PORT))
        try:
            port = int(raw)
        except ValueError:
            raise InputError(f"${PORT_ENV} = {raw!r}: expected a TCP port number") from None
    if not 0 < port < 65536:
        raise InputError(f"--port {port}: expected 1..65535")
    nodes = slurm.allocation_nodes(environ)
    if not nodes:
        raise InputError("--slurm: no SLURM allocation here (SLURM_JOB_NODELIST is not set); use --connect")
    return [f"tcp://{node}:{port}" for node in nodes]


def resolve_endpoints(args: argparse.Namespace) -> list[str]:
    """The control endpoints the UI connects to."""
    endpoints = [check_endpoint(e) for e in args.connect]
    if args.slurm:
        endpoints += slurm_endpoints(args.port)
    if not endpoints:
        from hdeem_watch.daemon.client import default_endpoints

        endpoints = [default_endpoints()[1]]
    return list(dict.fromkeys(endpoints))


def _run(args: argparse.Namespace) -> int:
    if not args.fps > 0:
        raise InputError(f"--fps {args.fps}: expected a positive number of frames per second")
    if not args.window > 0:
        raise InputError(f"--window {args.window}: expected a positive number of seconds")
    if args.duration is not None and not args.duration > 0:
        raise InputError(f"--duration {args.duration}: expected a positive number of seconds")
    endpoints = resolve_endpoints(args)
    stats_file = _open_stats(args.stats) if args.stats else None
    from hdeem_watch.tui.feed import FeedHub

    if args.headless or not (sys.stdout.isatty() and os.environ.get("TERM", "") != "dumb"):
        if stats_file is not None:
            stats_file.close()
        return _headless(FeedHub(endpoints, snapshot_hz=4.0), args)
    from hdeem_watch.tui.app import HdeemWatchApp

    hub = FeedHub(endpoints, snapshot_hz=min(10.0, max(1.0, args.fps)))
    app = HdeemWatchApp(hub, fps=args.fps, window_s=args.window, exit_after_s=args.duration)
    stats = None
    if stats_file is not None:
        from hdeem_watch.tui.stats import StatsWriter

        stats = StatsWriter(stats_file, lambda: app.frames, hub)
        stats.start()
    try:
        app.run()
    finally:
        if stats is not None:
            stats.stop()
    return 0


def _open_stats(path: str) -> TextIO:
    """Open the ``--stats`` file for appending, before anything starts.

    Raises:
        InputError: it cannot be written (missing directory, permissions, a directory).
    """
    try:
        return open(path, "a", encoding="utf-8")
    except OSError as error:
        raise InputError(f"--stats {path}: cannot write it ({error.strerror or error})") from None


def _headless(hub: Any, args: argparse.Namespace) -> int:
    """Text lines until ``--duration`` or Ctrl-C; exit 1 when a daemon never sent its stream (said
    on stderr, with the reason), so a script can tell."""
    from hdeem_watch.tui.headless import print_progress, silent_nodes

    if not args.headless:
        print("hdeem-watch tui: standard output is not a terminal; printing progress as text (--headless)",
              file=sys.stderr)
    hub.set_view(focus=-1, window_s=10.0, width=0)
    hub.start()
    try:
        print_progress(hub, duration_s=args.duration)
    except KeyboardInterrupt:
        return 130
    finally:
        hub.stop()
    silent = silent_nodes(hub.snapshots())
    for snap in silent:
        reason = snap.health.detail or "no reply"
        print(f"hdeem-watch tui: {snap.health.endpoint}: unreachable: {reason}", file=sys.stderr)
    return 1 if silent else 0
