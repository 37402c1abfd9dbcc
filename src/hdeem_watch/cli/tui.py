"""``hdeem-watch tui``: the live terminal UI for one or more node daemons.

``--connect ENDPOINT`` (repeatable) names a daemon's *control* endpoint; the UI asks it for the
stream endpoint. Without it the UI connects to the local daemon's default endpoint. ``--slurm``
connects to every node of the current SLURM allocation at ``tcp://<node>:<port>`` (port
:data:`hdeem_watch.addresses.CONTROL_PORT` unless ``--port`` or ``$HDEEM_WATCH_CONTROL_PORT`` says otherwise; the
daemons must listen there, e.g. ``remote_control = "tcp://*:5591"``).

TCP endpoints of a daemon with CURVE need its public key (``--server-key``, the environment or the
node's daemon config: :mod:`hdeem_watch.cli.curve_options`). Before the UI starts, every daemon is
asked for its status once, in parallel: a refused handshake (no key, a wrong key, a key the daemon
does not accept) ends the command at once with the reason (exit 2), instead of a UI that says
"connecting" forever; a daemon that is merely not running yet is left to the UI.
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import Any, TextIO

from hdeem_watch.cli.control_port import CONTROL_PORT, CONTROL_PORT_ENV, control_port
from hdeem_watch.cli.curve_options import add_server_key_argument, client_kwargs, curve_keys
from hdeem_watch.errors import InputError

#: How long the start-up check waits for each daemon's status.
PREFLIGHT_TIMEOUT_S = 3.0
ENDPOINT_SCHEMES = ("ipc://", "tcp://", "inproc://")


def register(subparsers: Any) -> None:
    """Add the ``tui`` subcommand."""
    parser = subparsers.add_parser(
        "tui",
        help="live terminal UI: power per DIMM pair, baselines, runs, calibration",
        description="Live terminal UI of one or more hdeem-watch daemons.\n\n"
        "keys: p pause, n/N next/previous node, +/- zoom, b measure the idle baseline,\n"
        "s stop the run, "
        "g per-pair calibration (g or Esc back), ? help, q quit",
        epilog="examples:\n"
        "  hdeem-watch tui                              # the local daemon\n"
        f"  hdeem-watch tui --connect tcp://node7:{CONTROL_PORT} --fps 2   # over slow ssh\n"
        "  hdeem-watch tui --slurm                      # every node of the allocation\n"
        "  hdeem-watch tui --headless --duration 60     # text lines for 60 s\n"
        "exit codes: 0 done, 1 a daemon never sent its stream (--headless; the reason\n"
        "  on stderr), 2 bad input (also: a daemon refused the CURVE handshake),\n"
        "  130 interrupted (--headless)",
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
        help=f"control port of the daemons for --slurm (default ${CONTROL_PORT_ENV} or {CONTROL_PORT})",
    )
    add_server_key_argument(parser)
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
        raise InputError(f"--connect {endpoint!r}: expected a ZeroMQ endpoint such as tcp://node7:{CONTROL_PORT} or ipc:///path")
    return endpoint


def slurm_endpoints(port: int | None = None, env: dict[str, str] | None = None) -> list[str]:
    """Control endpoints of every node of the allocation.

    Raises:
        InputError: outside an allocation, or for a bad port.
    """
    from hdeem_watch import slurm

    environ = dict(os.environ if env is None else env)
    port = control_port(port, environ)
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
        from hdeem_watch.wire.client import default_endpoints

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
    curve = curve_keys(args)
    refused = preflight(endpoints, curve)
    if refused:
        raise InputError(refused[0] if len(refused) == 1 else f"{refused[0]} (and {len(refused) - 1} more)")
    stats_file = _open_stats(args.stats) if args.stats else None
    from hdeem_watch.tui.feed import FeedHub

    if args.headless or not (sys.stdout.isatty() and os.environ.get("TERM", "") != "dumb"):
        if stats_file is not None:
            stats_file.close()
        return _headless(FeedHub(endpoints, snapshot_hz=4.0, curve=curve), args)
    from hdeem_watch.tui.app import HdeemWatchApp

    hub = FeedHub(endpoints, snapshot_hz=min(10.0, max(1.0, args.fps)), curve=curve)
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


def preflight(endpoints: list[str], curve: Any, timeout_s: float = PREFLIGHT_TIMEOUT_S) -> list[str]:
    """Ask every TCP daemon for its status at once; return one line per refused handshake.

    A daemon that does not answer (not running yet, a firewall) is not an error here: the UI shows
    it as connecting and keeps trying. ipc endpoints have no handshake to fail.
    """
    from concurrent.futures import ThreadPoolExecutor

    from hdeem_watch.wire.client import ControlClient, DaemonUnreachable, HandshakeFailed

    def check(endpoint: str) -> str | None:
        with ControlClient(endpoint, timeout_s=timeout_s, **client_kwargs(curve)) as client:
            try:
                client.call("status")
            except HandshakeFailed as error:
                return str(error)
            except DaemonUnreachable:
                return None
            except Exception:  # an error reply: the daemon answers, the UI shows the rest
                return None
        return None

    remote = [e for e in endpoints if e.startswith("tcp://")]
    if not remote:
        return []
    with ThreadPoolExecutor(max_workers=min(32, len(remote))) as pool:
        return [reason for reason in pool.map(check, remote) if reason is not None]


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
        from hdeem_watch.cli.demo import why_no_tui

        print(f"hdeem-watch tui: {why_no_tui()}; printing progress as text (--headless)", file=sys.stderr)
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
