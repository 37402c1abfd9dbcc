"""``hdeem-watch bench``: run STREAM-like kernels in thread sweeps, optionally announced to a daemon.

Example::

    hdeem-watch bench --kernels read,copy,triad --threads 1,2,4-24:4 --elements 100000000 --repeat 10
    hdeem-watch bench --kernels all+idle --threads 1,2 --daemon ipc:///run/hdeem-watch/control.sock --json

Runs are sized by time: each lasts ``--seconds`` (default 2 s, twice what the daemon's guard rail
needs to measure a run: 100 samples of a 100 Sa/s sensor), with the pass count derived from one
timed probe pass (a run the probe's slowed timing left under half its time, and the daemon did not
calibrate, is run once more with the passes it missed); ``--repeat N`` gives exactly N passes
instead. Runs the daemon still could not
calibrate get one summary warning that says how to lengthen them. Ctrl-C aborts the announced run
(stored, not calibrated) before exiting 130, so the daemon takes the next run at once.

Output: a table (default), or with ``--json`` one JSON object per run and line on stdout with at
least ``kernel, threads, elements, seconds, lines_per_s, dram_bytes_per_s, stream_bytes_per_s``. A
progress bar goes to stderr when stderr is a terminal. Exit codes: 0 success, 2 bad input (one line
on stderr), 1 the daemon still refused a run after ``--wait`` seconds (another run was open), or
would not take runs from this user at all (authorization: root, the daemon's user or the owner of
a job running on the node; said before any kernel runs).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import math
import sys
from typing import TYPE_CHECKING, Any, TextIO

from hdeem_watch import slurm
from hdeem_watch.bench.announce import WAIT_S, RunRefused
from hdeem_watch.bench.runner import BACKENDS, MAX_TIMED_REPEAT, RunResult, run_one, validate
from hdeem_watch.bench.schedule import sweep
from hdeem_watch.cli.curve_options import add_server_key_argument, client_kwargs, curve_keys
from hdeem_watch.cli.numbers import counted
from hdeem_watch.errors import InputError

if TYPE_CHECKING:
    from hdeem_watch.bench.announce import Announcer

DEFAULT_ELEMENTS = 1 << 25
#: Fewest seconds a run needs for the daemon's guard rail: 100 samples of a 100 Sa/s sensor
#: (``hdeem_watch.calibrate.group_rows.DEFAULT_MIN_SAMPLES``, HDEEM's rate).
MEASURABLE_S = 1.0
#: Default length of a run: the guard rail's 1 s with a margin of 2 (announce latency, a slower poll).
DEFAULT_SECONDS = 2.0 * MEASURABLE_S


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


def _seconds(text: str) -> float:
    """Parse ``--seconds``: a positive, finite number."""
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text!r}: expected a positive number of seconds, e.g. 2")
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
    parser.add_argument("--seconds", type=_seconds, default=DEFAULT_SECONDS, metavar="S",
                        help=f"length of each run; the passes are counted from a timed probe pass "
                             f"(default {DEFAULT_SECONDS:g}: the daemon needs >= {MEASURABLE_S:g} s to "
                             "measure a run)")
    parser.add_argument("--repeat", type=int, metavar="N",
                        help="exactly N passes over the arrays per run, instead of --seconds")
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
    """The result table, 80 columns wide."""
    print(f"{'kernel':<9}{'threads':>8}{'elements':>11}{'passes':>7}{'seconds':>8}{'Mline/s':>9}"
          f"{'DRAM GB/s':>10}{'STREAM GB/s':>12}  run", file=out)
    for r in results:
        run_id = r.announce.get("run_id", "")
        print(f"{r.spec.kernel:<9}{r.spec.threads:>8}{r.spec.elements:>11}{r.spec.repeat:>7}"
              f"{r.seconds:>8.3f}{r.lines_per_s / 1e6:>9.1f}{r.dram_bytes_per_s / 1e9:>10.2f}"
              f"{r.stream_bytes_per_s / 1e9:>12.2f}  {run_id}", file=out)
    print("DRAM GB/s: what moves, write-allocate reads included; STREAM GB/s: STREAM's\n"
          "count (copy/scale 2, add/triad 3 words per element)", file=out)


def _not_calibrated(result: RunResult) -> str | None:
    """Why the daemon did not calibrate with the run (e.g. too short to measure), or None."""
    record = result.announce.get("daemon")
    if not isinstance(record, dict) or record.get("fit") is not None or not record.get("model_error"):
        return None
    return f"run {record.get('run_id')} ({result.spec.kernel} x{result.spec.threads}): {record['model_error']}"


def rerun_passes(result: RunResult, seconds: float | None) -> int | None:
    """Passes for running ``result``'s run again, or None when it stands.

    A run sized by time (``seconds``) is timed by a probe just before it; on a shared node the
    probe can be slowed by another process and the run then comes out far too short (0.2 s of 2 s
    was seen under load). Such a run, if the daemon did not calibrate it, is run once more with its
    pass count scaled by the time it missed; a run the daemon took, or one near its time, stands."""
    if seconds is None or _not_calibrated(result) is None or result.seconds >= 0.5 * seconds:
        return None
    return max(result.spec.repeat + 1, min(MAX_TIMED_REPEAT, math.ceil(1.1 * result.spec.repeat * seconds / result.seconds)))


def too_short_summary(results: list[RunResult], seconds: float | None) -> str | None:
    """One warning for all runs the daemon did not calibrate, with the fix; None when it took them all.

    ``seconds`` is the ``--seconds`` the runs were sized by (None: ``--repeat`` gave exact counts).
    """
    refused = [(r, reason) for r in results if (reason := _not_calibrated(r)) is not None]
    if not refused:
        return None
    shortest = min(r.seconds for r, _ in refused)
    if seconds is not None:
        factor = max(2.0, 2.0 * MEASURABLE_S / max(shortest, 1e-3))
        fix = f"--seconds {math.ceil(seconds * factor):g}"
    else:
        fix = f"drop --repeat (runs then last --seconds {DEFAULT_SECONDS:g})"
    runs = "run was" if len(refused) == 1 else "runs were"
    return (f"{len(refused)} of {len(results)} {runs} not calibrated (shortest {shortest:.2f} s; "
            f"e.g. {refused[0][1]}); make them longer: {fix}")


def _run(args: argparse.Namespace) -> int:
    elements = _elements(args.elements)
    if args.repeat is not None and args.repeat < 1:
        raise InputError(f"--repeat {args.repeat}: expected at least 1 pass")
    by_time = None if args.repeat is not None else args.seconds
    specs = sweep(args.kernels, args.threads, elements, args.repeat or 1)
    allowed = slurm.allowed_cpus()
    validate(specs, allowed, oversubscribe=args.oversubscribe)
    warned: set[str] = set()
    progress = _Progress(len(specs), sys.stderr)

    def warn(message: str) -> None:
        if message not in warned:
            warned.add(message)
            progress.clear()
            print(f"hdeem-watch bench: warning: {message}", file=sys.stderr)

    announcer = _announcer(args, warn) if args.daemon else None
    if isinstance(announcer, int):
        return announcer
    run = functools.partial(run_one, backend=args.backend, allowed=allowed, oversubscribe=args.oversubscribe,
                            on_start=announcer.on_start if announcer else None,
                            on_stop=announcer.on_stop if announcer else None)
    results: list[RunResult] = []
    refused: RunRefused | None = None
    try:
        for i, spec in enumerate(specs):
            progress.show(i, f"{spec.kernel} x{spec.threads}")
            try:
                result = run(spec, seconds=by_time)
                if (passes := rerun_passes(result, by_time)) is not None:
                    warn(f"run {result.announce['daemon'].get('run_id')} ({spec.kernel} x{spec.threads}) lasted "
                         f"{result.seconds:.2f} s of the {by_time:g} s asked (the node was busier while its passes "
                         f"were timed): running it again with {passes} passes")
                    result = run(dataclasses.replace(result.spec, repeat=passes))
            except RunRefused as error:
                refused = error
                break
            for message in result.warnings:
                warn(message)
            results.append(result)
            if args.json:
                print(json.dumps(_jsonable(result.to_dict())), flush=True)
        progress.show(len(results), "done" if refused is None else "stopped")
        progress.clear()
    except KeyboardInterrupt:
        progress.clear()
        aborted = announcer.abort_open() if announcer is not None else None
        done = f"{len(results)} of {counted(len(specs), 'run')} done"
        print(f"hdeem-watch bench: interrupted; {done}" + (f"; run {aborted} aborted" if aborted else ""),
              file=sys.stderr)
        return 130
    finally:
        if announcer is not None:
            announcer.close()
    if not args.json:
        _table(results, sys.stdout)
    if (summary := too_short_summary(results, by_time)) is not None:
        warn(summary)
    if refused is not None:
        print(f"hdeem-watch bench: error: {refused}; {len(results)} of {counted(len(specs), 'run')} done", file=sys.stderr)
        return 1
    return 0


def _announcer(args: argparse.Namespace, warn: Any) -> Announcer | int:
    """The announcer for ``--daemon`` after checking the daemon answers and takes this user's
    runs; exit code 1 (said on stderr) when it would refuse them."""
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
    return announcer


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
