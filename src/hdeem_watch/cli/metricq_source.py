"""``hdeem-watch metricq-source``: publish a node daemon's stream to a MetricQ network.

Usage::

    hdeem-watch metricq-source --server amqp://USER:PASSWORD@HOST/ [--token TOKEN] [--stream EP ...]
        [--config FILE] [--prefix PREFIX] [--metrics power,above_baseline,calibrated_currents]
        [--server-file FILE] [--token-file FILE] [--status-file FILE] [--duration S]

Reads the daemon's stream (it adds no sensor polling and never slows the daemon) and publishes per
node each sensor's power at its native rate, each DIMM pair's power above its idle baseline and the
calibrated DRAM currents. Settings come from the ``[metricq]`` table of ``--config``, then
``HDEEM_WATCH_METRICQ_*`` variables, then flags. It runs until SIGINT/SIGTERM (or ``--duration``),
reconnecting to MetricQ with a bounded backoff; its state is logged and written to ``--status-file``.
Needs the optional ``metricq`` package (``pip install 'hdeem-watch[metricq]'``). See docs/metricq.md.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import signal
import sys
from typing import Any

from hdeem_watch.errors import InputError
from hdeem_watch.metricq.naming import FAMILIES
from hdeem_watch.metricq.settings import SourceSettings, load_source_settings

EXAMPLES = """examples:
  hdeem-watch metricq-source --server amqp://hw:PASSWORD@rabbit.example/ --prefix taurus.hdeem
  hdeem-watch metricq-source --config /etc/hdeem-watch/hdeem-watchd.toml   # reads its [metricq] table
  hdeem-watch metricq-source --server-file /etc/hdeem-watch/metricq-url --token source-hdeem-node7 \\
      --stream tcp://node7:5590 --status-file /run/hdeem-watch/metricq.json"""


def register(subparsers: Any) -> None:
    """Add ``metricq-source``."""
    parser = subparsers.add_parser(
        "metricq-source", aliases=["metricq_source"],
        help="publish the daemon's stream (power, above-baseline power, calibrated currents) to MetricQ",
        description="Publish one or more node daemons' streams to a MetricQ network as a MetricQ source.",
        epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", metavar="FILE", help="TOML file whose [metricq] table holds the settings")
    parser.add_argument("--server", metavar="URL", help="AMQP URL of the MetricQ broker (amqp://USER:PASSWORD@HOST/)")
    parser.add_argument("--server-file", metavar="FILE", help="file holding the AMQP URL (mode 0600)")
    parser.add_argument("--token", metavar="TOKEN", help="this source's MetricQ token (default: source-hdeem-watch-HOST)")
    parser.add_argument("--token-file", metavar="FILE", help="file holding the token (mode 0600)")
    parser.add_argument("--prefix", metavar="PREFIX", help="site prefix of every metric name (default: hdeem)")
    parser.add_argument("--metrics", metavar="LIST",
                        help=f"comma-separated metric families (default: all of {','.join(FAMILIES)})")
    parser.add_argument("--stream", metavar="EP", action="append", dest="connect",
                        help="a daemon's stream endpoint (its pub socket); repeat for several (default: the "
                             "local daemon)")
    parser.add_argument("--connect", metavar="EP", action="append", dest="control_given", help=argparse.SUPPRESS)
    parser.add_argument("--server-key", "--curve-server-key", metavar="FILE", dest="curve_server_key",
                        help="the daemons' public CURVE certificate (server.key) for TCP streams with CURVE")
    parser.add_argument("--curve-client-key", metavar="FILE",
                        help="this source's secret CURVE certificate (.key_secret) for daemons with an allow-list")
    parser.add_argument("--status-file", metavar="FILE", help="write the status as JSON to FILE")
    parser.add_argument("--status-interval", metavar="S", type=float, help="status period in s (default: 10)")
    parser.add_argument("--reconnect-max", metavar="S", type=float,
                        help="longest wait between two attempts to reach MetricQ (default: 30)")
    parser.add_argument("--buffer-points", metavar="N", type=int,
                        help="data points kept while MetricQ is unreachable (default: 500000)")
    parser.add_argument("--duration", metavar="S", type=float, help="stop after S seconds (default: run until signalled)")
    parser.add_argument("--flush-interval", metavar="S", type=float, default=0.2,
                        help="how often waiting points are sent, one chunk per metric (default: 0.2)")
    parser.add_argument("-v", "--verbose", action="store_true", help="log the metricq library's messages too")
    parser.set_defaults(func=run)


def settings_from(args: argparse.Namespace) -> SourceSettings:
    """The checked settings of ``args`` (flags over environment over ``--config``)."""
    overrides = {
        "server": args.server, "server_file": args.server_file, "token": args.token,
        "token_file": args.token_file, "prefix": args.prefix, "metrics": args.metrics,
        "connect": ",".join(args.connect) if args.connect else None, "status_file": args.status_file,
        "status_interval_s": args.status_interval, "reconnect_max_s": args.reconnect_max,
        "buffer_points": args.buffer_points, "curve_server_key_file": args.curve_server_key,
        "curve_client_key_file": args.curve_client_key,
    }
    return load_source_settings(args.config, overrides=overrides)


def run(args: argparse.Namespace) -> int:
    """Run the source until signalled (or ``--duration``); 0 on a clean stop."""
    if args.control_given:  # one meaning per flag: --connect is a control endpoint in every command
        raise InputError(f"--connect {args.control_given[0]}: metricq-source reads a daemon's stream; give its "
                         "stream endpoint with --stream EP (e.g. tcp://node7:5590)")
    settings = settings_from(args)
    if args.duration is not None and not args.duration > 0:
        raise InputError(f"--duration {args.duration!r}: expected a positive number of seconds")
    if not args.flush_interval > 0:
        raise InputError(f"--flush-interval {args.flush_interval!r}: expected a positive number of seconds")
    try:
        from hdeem_watch.metricq.source import SourceRunner, curve_options
    except ImportError as error:
        raise InputError(f"the metricq package is not installed ({error}); "
                         "pip install 'hdeem-watch[metricq]'") from None
    from hdeem_watch.wire.client import default_endpoints

    curve_options(settings)  # a bad certificate is bad input, before anything starts
    endpoints = [e.strip() for e in settings.connect.split(",") if e.strip()] or [default_endpoints()[0]]
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    if not args.verbose:  # the source logs each failure itself, in one line
        for name in ("metricq", "aio_pika", "aiormq"):
            logging.getLogger(name).setLevel(logging.CRITICAL)
    runner = SourceRunner(settings, endpoints, flush_interval_s=args.flush_interval)
    asyncio.run(_main(runner, args.duration))
    print(runner.status.line())
    if runner.status.broker_connects == 0:  # never reached MetricQ: nothing was published
        print("hdeem-watch metricq-source: error: never reached the MetricQ broker; nothing was published",
              file=sys.stderr)
        return 1
    return 0


async def _main(runner: Any, duration_s: float | None) -> None:
    loop = asyncio.get_running_loop()
    for signum in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(signum, runner.stop)
    if duration_s is not None:
        loop.call_later(duration_s, runner.stop)
    await runner.run()
