"""``hdeem-watch daemon``: run the node daemon (DESIGN.md §6–7).

Works without a config file: ``hdeem-watch daemon --source sim --pub EP --control EP --state-dir DIR``.
Settings come from ``--config FILE`` (TOML), then ``HDEEM_WATCH_*`` variables, then these flags
(see :mod:`hdeem_watch.config`). SIGTERM and SIGINT end it cleanly (exit 0). Bad input (a bad flag,
config key, busy endpoint or state directory, an unavailable source with its reason) is one line
on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import logging
import re
import signal
import sys
from typing import Any

from hdeem_watch.config import SOURCE_KINDS, load_settings
from hdeem_watch.errors import InputError
from hdeem_watch.sources.options import add_source_flags, source_flag_overrides


def register(subparsers: Any) -> None:
    """Add the ``daemon`` subcommand."""
    parser = subparsers.add_parser(
        "daemon",
        help="run the node daemon (sources → ZeroMQ stream, runs, baselines, calibration)",
        description="Run the node daemon. Without flags: the simulated node, ipc endpoints in the "
        "runtime directory, state in the state directory.",
    )
    parser.add_argument("--config", metavar="FILE", help="TOML settings file (see daemon/hdeem-watchd.toml)")
    parser.add_argument("--source", choices=SOURCE_KINDS, help="power source (default sim)")
    parser.add_argument("--pub", metavar="ENDPOINT", help="stream endpoint (default ipc://RUNTIME/pub.sock)")
    parser.add_argument("--control", metavar="ENDPOINT", help="control endpoint (default ipc://RUNTIME/control.sock)")
    parser.add_argument("--remote-control", metavar="ENDPOINT",
                        help="a second control endpoint for other nodes, beside --control (e.g. tcp://*:5591)")
    parser.add_argument("--state-dir", metavar="DIR", help="directory of state.db")
    parser.add_argument("--runtime-dir", metavar="DIR", help="directory of the default ipc sockets")
    parser.add_argument("--node", metavar="NAME", help="node name (default: short host name)")
    parser.add_argument("--speed", type=float, metavar="X", help="sim/replay speed factor (default 1)")
    parser.add_argument("--seed", type=int, metavar="N", help="sim random seed")
    parser.add_argument("--replay-file", metavar="FILE", help="recording for --source replay")
    parser.add_argument("--replay-loop", action="store_true", default=None,
                        help="replay: start the recording again at its end (default: stop there)")
    parser.add_argument("--record", metavar="FILE", help="record every sample to FILE (replayable CSV)")
    parser.add_argument("--curve-secret-key", metavar="FILE", help="CURVE certificate (.key_secret) of the daemon")
    parser.add_argument("--curve-clients", metavar="DIR", help="public keys of the clients allowed under CURVE")
    parser.add_argument("--allow-insecure-tcp", action="store_true", default=None,
                        help="accept TCP endpoints on a non-loopback address without CURVE (unencrypted, "
                        "unauthenticated: anyone who reaches the port may read the stream and control runs)")
    parser.add_argument("--gen-keys", metavar="DIR", help="write a new CURVE key pair (server.key, "
                        "server.key_secret) to DIR and exit; an existing pair is kept unless --force")
    parser.add_argument("--key-name", metavar="NAME", default="server",
                        help="--gen-keys: file name of the pair (default server; <user> for a client key to "
                        "register in curve_clients_dir as <user>.key)")
    parser.add_argument("--force", action="store_true", help="--gen-keys: replace an existing key pair")
    parser.add_argument("--prometheus", type=int, metavar="PORT", help="serve Prometheus metrics on PORT")
    parser.add_argument("--poll-interval", type=float, metavar="S", help="source poll period in s (default 0.04)")
    parser.add_argument("--memspec", metavar="PRESET|FILE", help="memspec of one DIMM for the run model")
    parser.add_argument("--sim-age", metavar="PAIR=±X%/h",
                        help="sim: a DIMM pair's currents drift in sim time, e.g. DDR_CD=+30%%/h "
                        "(comma-separated; @600s delays the start)")
    parser.add_argument("--sim-node", choices=("haswell", "ddr5"),
                        help="sim: the simulated node (default haswell: Taurus' Haswell-EP with HDEEM's DIMM pairs; "
                        "ddr5: 2 sockets x 8 DDR5 channels, RAPL DRAM per socket)")
    parser.add_argument("--counters", choices=("auto", "none", "sim", "perf", "replay"),
                        help="memory-controller counters for each window's DRAM commands (default auto: the "
                             "source's own when they can be opened, else none; logged once)")
    parser.add_argument("--log-level", choices=("debug", "info", "warning", "error"),
                        help="log verbosity on stderr (default: log_level from the config file, else info)")
    add_source_flags(parser)
    parser.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    if args.gen_keys:
        from hdeem_watch.wire.keys import generate_keys

        if not re.fullmatch(r"[A-Za-z0-9_.@-]+", args.key_name) or args.key_name.startswith("."):
            raise InputError(f"--key-name {args.key_name!r}: expected a file name (letters, digits, _ . @ -)")
        public, secret = generate_keys(args.gen_keys, args.key_name, force=args.force)
        if args.key_name == "server":
            print(f"public key (give to clients): {public}\nsecret key (--curve-secret-key): {secret}")
        else:
            print(f"public key (register it in the daemon's curve_clients_dir): {public}\n"
                  f"secret key (--client-key): {secret}")
        return 0
    from hdeem_watch.daemon.service import Daemon
    from hdeem_watch.daemon.shell.publisher import daemon_context

    settings = load_settings(
        args.config,
        overrides={
            "source": args.source, "pub": args.pub, "control": args.control,
            "remote_control": args.remote_control, "state_dir": args.state_dir,
            "runtime_dir": args.runtime_dir, "node": args.node, "speed": args.speed, "seed": args.seed,
            "replay_file": args.replay_file, "replay_loop": args.replay_loop, "record_file": args.record,
            "curve_secret_key_file": args.curve_secret_key, "curve_clients_dir": args.curve_clients, "prometheus_port": args.prometheus,
            "poll_interval_s": args.poll_interval, "memspec": args.memspec, "log_level": args.log_level,
            "allow_insecure_tcp": args.allow_insecure_tcp, "sim_age": args.sim_age,
            "sim_node": args.sim_node,
            "counters": args.counters,
            **source_flag_overrides(args),
        },
        check_model=True,
    )
    logging.basicConfig(level=settings.log_level.upper(), stream=sys.stderr,
                        format="%(asctime)s hdeem-watchd %(levelname)s %(message)s")
    context = daemon_context()
    daemon = Daemon(settings, context=context)
    daemon.start()

    def stop(signum: int, frame: Any) -> None:
        daemon.request_stop()

    previous = {sig: signal.signal(sig, stop) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        daemon.run()
    finally:
        daemon.close()
        context.destroy(linger=0)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0
