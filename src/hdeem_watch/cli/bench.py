"""``hdeem-watch bench``: run STREAM-like kernels in thread sweeps, optionally announced to a daemon.

Example::

    hdeem-watch bench --kernels read,copy,triad --threads 1,2,4-24:4 --elements 100000000 --repeat 10
    hdeem-watch bench --kernels all+idle --threads 24 --elements 2e8 --repeat 20 \\
        --daemon ipc:///run/hdeem-watch/control.sock --json

Output: a table (default), or with ``--json`` one JSON object per run and line on stdout with at
least ``kernel, threads, elements, seconds, lines_per_s, dram_bytes_per_s, stream_bytes_per_s``. A
progress bar goes to stderr when stderr is a terminal. Exit codes: 0 success, 2 bad input (one line
on stderr), 1 the daemon still refused a run after ``--wait`` seconds (another run was open), or
would not take runs from this user at all (authorization: root, the daemon's user or the owner of
a job running on the node; said before any kernel runs).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any, TextIO

from hdeem_watch import slurm
from hdeem_watch.bench.announce import WAIT_S, RunRefused
from hdeem_watch.bench.runner import BACKENDS, RunResult, run_one, validate
from hdeem_watch.bench.schedule import sweep
from hdeem_watch.cli.curve_options import add_server_key_argument, client_kwargs, curve_keys
from hdeem_watch.errors import InputError

DEFAULT_ELEMENTS = 1 << 25


def _elements(text: str) -> int:
    """Parse ``--elements``: an integer, ``1e8`` or ``2**27``."""
    raw = text.strip().replace("_", "")
    try:
        if "**" in raw:
            base, exp = raw.split("**", 1)
            value = int(base) ** int(exp)
        else:
            number = float(raw)
            if not math.isfinite(number) or number != int(number):
                raise ValueError
            value = int(number)
    except (ValueError, OverflowError):
        raise InputError(f"--elements {text!r}: not a whole number; expected e.g. 100000000, 1e8 or 2**27") from None
    return value


def register(subparsers: Any) -> None:
    """Add the ``bench`` subcommand."""
    parser = subparsers.add_parser(
        "bench", help="run STREAM-like kernels (thread sweeps), optionally announced to a daemon",
        description="Run stride-8 STREAM-like kernels on pinned workers and report line rate and DRAM "
                    "bandwidth per run.")
    parser.add_argument("--kernels", default="all",
                        help="comma-separated: read,assign,scale,add|addition,triad,copy,selfscale,idle; "
                             "'all' = the seven STREAM-like kernels, 'all+idle' adds idle (default all)")
    parser.add_argument("--threads", default="1", help="thread counts, e.g. 1,2,4-24:4 (default 1)")
    parser.add_argument("--elements", type=str, default=str(DEFAULT_ELEMENTS),
                        help=f"doubles per array (default {DEFAULT_ELEMENTS}); use >> the LLC")
    parser.add_argument("--repeat", type=int, default=10, help="passes over the arrays per run (default 10)")
    parser.add_argument("--daemon", metavar="ENDPOINT",
                        help="announce each run (run.start/run.stop) to the daemon's control endpoint")
    add_server_key_argument(parser)
    parser.add_argument("--json", action="store_true", help="one JSON object per run and line on stdout")
    parser.add_argument("--backend", choices=BACKENDS, default="thread",
                        help="workers as threads (default) or forked processes")
    parser.add_argument("--oversubscribe", action="store_true",
                        help="allow more threads than allowed CPUs (round-robin pinning)")
    parser.add_argument("--timeout", type=float, default=5.0, help="daemon reply timeout in s (default 5)")
    parser.add_argument("--wait", type=float, default=WAIT_S, metavar="S",
                        help="while the daemon has another run open, ask again every second for up to S "
                             f"seconds per run, then stop with exit code 1 (default {WAIT_S:g})")
    parser.set_defaults(func=_run)


class _Progress:
    """A one-line progress bar on a terminal (stderr); silent elsewhere."""

    def __init__(self, total: int, stream: TextIO) -> None:
        self.total = total
        self.stream = stream
        self.enabled = stream.isatty()

    def show(self, done: int, label: str) -> None:
        if not self.enabled:
            return
        width = 30
        filled = int(width * done / max(1, self.total))
        bar = "#" * filled + "-" * (width - filled)
        self.stream.write(f"\r[{bar}] {done}/{self.total} {label:<28.28}")
        self.stream.flush()

    def clear(self) -> None:
        if self.enabled:
            self.stream.write("\r" + " " * 72 + "\r")
            self.stream.flush()


def _table(results: list[RunResult], out: TextIO) -> None:
    header = f"{'kernel':<10}{'threads':>8}{'elements':>13}{'repeat':>7}{'seconds':>10}" \
             f"{'Mlines/s':>11}{'DRAM GB/s':>11}{'STREAM GB/s':>13}  run_id"
    print(header, file=out)
    for r in results:
        run_id = r.announce.get("run_id", "")
        print(f"{r.spec.kernel:<10}{r.spec.threads:>8}{r.spec.elements:>13}{r.spec.repeat:>7}"
              f"{r.seconds:>10.4f}{r.lines_per_s / 1e6:>11.1f}{r.dram_bytes_per_s / 1e9:>11.2f}"
              f"{r.stream_bytes_per_s / 1e9:>13.2f}  {run_id}", file=out)
    print("DRAM GB/s: what moves, write-allocate reads included; STREAM GB/s: STREAM's count "
          "(copy/scale 2, add/triad 3 words per element)", file=out)


def _not_calibrated(result: RunResult) -> str | None:
    """Why the daemon did not calibrate with the run (e.g. too short to measure), or None."""
    record = result.announce.get("daemon")
    if not isinstance(record, dict) or record.get("fit") is not None or not record.get("model_error"):
        return None
    return f"run {record.get('run_id')} ({result.spec.kernel} x{result.spec.threads}): {record['model_error']}"


def _run(args: argparse.Namespace) -> int:
    elements = _elements(args.elements)
    specs = sweep(args.kernels, args.threads, elements, args.repeat)
    allowed = slurm.allowed_cpus()
    validate(specs, allowed, oversubscribe=args.oversubscribe)
    announcer = None
    warned: set[str] = set()

    def warn(message: str) -> None:
        if message not in warned:
            warned.add(message)
            progress.clear()
            print(f"hdeem-watch bench: warning: {message}", file=sys.stderr)

    progress = _Progress(len(specs), sys.stderr)
    if args.daemon:
        from hdeem_watch.bench.announce import Announcer
        from hdeem_watch.wire.client import ControlClient

        if not (math.isfinite(args.wait) and args.wait >= 0):
            raise InputError(f"--wait {args.wait:g}: expected a number of seconds >= 0")
        client = ControlClient(args.daemon, timeout_s=args.timeout, **client_kwargs(curve_keys(args)))
        announcer = Announcer(args.daemon, timeout_s=args.timeout, metadata=slurm.job_metadata(), warn=warn,
                              wait_s=args.wait, client=client)
        announcer.check()
        if (refusal := _refusal(client)) is not None:
            announcer.close()
            print(f"hdeem-watch bench: error: --daemon {args.daemon}: {refusal}", file=sys.stderr)
            return 1
    results: list[RunResult] = []
    refused: RunRefused | None = None
    try:
        for i, spec in enumerate(specs):
            progress.show(i, f"{spec.kernel} x{spec.threads}")
            try:
                result = run_one(spec, backend=args.backend, allowed=allowed, oversubscribe=args.oversubscribe,
                                 on_start=announcer.on_start if announcer else None,
                                 on_stop=announcer.on_stop if announcer else None)
            except RunRefused as error:
                refused = error
                break
            for message in result.warnings:
                warn(message)
            if (reason := _not_calibrated(result)) is not None:
                warn(reason)
            results.append(result)
            if args.json:
                print(json.dumps(_jsonable(result.to_dict())), flush=True)
        progress.show(len(results), "done" if refused is None else "stopped")
        progress.clear()
    finally:
        if announcer is not None:
            announcer.close()
    if not args.json:
        _table(results, sys.stdout)
    if refused is not None:
        print(f"hdeem-watch bench: error: {refused}; {len(results)} of {len(specs)} runs done", file=sys.stderr)
        return 1
    return 0


def _refusal(client: Any) -> str | None:
    """Why the daemon would refuse this user's runs (``whoami``), before any kernel runs; None when
    it would take them, or when it is too old to tell."""
    from hdeem_watch.wire.client import ControlError, DaemonUnreachable

    try:
        me = client.call("whoami")
    except (ControlError, DaemonUnreachable):
        return None
    if not isinstance(me, dict) or me.get("may_change_state") is not False:
        return None
    return (f"the daemon would not record runs from {me.get('peer')}: {me.get('reason')} "
            "(run inside your SLURM job on that node, or as root)")


def _jsonable(value: Any) -> Any:
    """Replace non-finite floats by None so every line is strict JSON."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    return value
