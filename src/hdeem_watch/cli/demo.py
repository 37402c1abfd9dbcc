"""``hdeem-watch demo``: the embedded default — a simulated node, its daemon, a benchmark schedule
and the live TUI, in one command.

It starts ``hdeem-watch daemon --source sim`` as a subprocess on ipc endpoints in a temporary
runtime directory, a schedule thread that announces runs (idle + the seven kernels at 24 threads,
then other thread counts) and the TUI connected to the daemon through the wire protocol. Within a
minute the calibration panel converges from the datasheet currents (about 2× too much energy)
toward the simulation's hidden truth. ``--headless`` prints the same progress as text lines. The
daemon is stopped on exit, on Ctrl-C, on SIGTERM and when the terminal hangs up (SIGHUP), and
gets SIGTERM from the kernel when the demo is killed outright (``kill -9``; Linux).
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import time
from pathlib import Path
from types import FrameType
from typing import Any

from hdeem_watch.errors import InputError

#: The demo's initial plot window: its runs last 1–2 s, so 30 s shows a dozen of them as steps
#: (the tui's default is 60 s, for real benchmark runs of tens of seconds).
DEMO_WINDOW_S = 30.0


def register(subparsers: Any) -> None:
    """Add the ``demo`` subcommand."""
    parser = subparsers.add_parser(
        "demo",
        help="simulated node + daemon + benchmark schedule + live TUI (the embedded default)",
        description="Run a simulated Haswell node with its daemon, a benchmark schedule and the live TUI; "
        "watch the DRAM model's currents calibrate. Ctrl-C or q stops everything.",
        epilog="examples:\n"
        "  hdeem-watch demo                             # the TUI until q\n"
        "  hdeem-watch demo --headless --duration 60    # text lines for 60 s (CI)\n"
        "  hdeem-watch demo --state-dir ~/hw-demo       # keep the state and its log\n"
        "exit codes: 0 done, 1 the daemon did not start, 2 bad input,\n"
        "  130 interrupted (--headless)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--node", default="haswell", metavar="NAME",
                        help="the simulated node: haswell (default; 2 x 12 cores, 8 DDR4 DIMMs, HDEEM's DIMM pairs) or "
                        "ddr5 (2 x 56 cores, 2 x 8 DDR5 DIMMs, RAPL DRAM per socket, Sapphire Rapids' IMC counters)")
    parser.add_argument("--headless", action="store_true", help="print progress as text lines instead of the TUI")
    parser.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds (default: until q or Ctrl-C)")
    parser.add_argument("--state-dir", default=None, metavar="DIR",
                        help="daemon state directory, kept afterwards with the daemon's log DIR/daemon.log "
                        "(default: a temporary directory, removed with its log)")
    parser.add_argument("--speed", type=float, default=1.0, help="time factor of the simulated node (default 1)")
    parser.add_argument("--fps", type=float, default=10.0, help="TUI frames per second (default 10)")
    parser.add_argument("--window", type=float, default=DEMO_WINDOW_S, metavar="S",
                        help=f"initial plot window in seconds (default {DEMO_WINDOW_S:g}: shorter than the tui's 60, "
                        "so the demo's 1–2 s runs show as steps; +/- zoom)")
    parser.add_argument("--sim-age", default=None, metavar="PAIR=±X%/h",
                        help="a DIMM pair of the simulated node ages: its currents drift in sim time, e.g. "
                        "DDR_CD=+30%%/h (with --speed 60 an hour passes in a minute); the calibration's "
                        "drift detector should name that pair")
    parser.add_argument("--counters", choices=("sim", "none"), default="sim",
                        help="where the runs' DRAM commands come from: sim = the simulated node's memory-controller "
                        "counters (default; a Haswell-EP IMC's ACT/PRE/CAS/CKE counts), none = the kernel model only "
                        "(its intervals then carry the unknown address mapping)")
    parser.add_argument("--no-holdout", dest="holdout", action="store_false",
                        help="no hold-out runs (by default each round from the fifth adds one kernel the fit never "
                        "sees, predicted with the fit from before it)")
    parser.add_argument("--report", default=None, metavar="DIR",
                        help="write the report (hdeem-watch report) of the demo's state into DIR at the end")
    parser.set_defaults(func=_run)


def _check(args: argparse.Namespace) -> None:
    if args.duration is not None and not args.duration > 0:
        raise InputError(f"--duration {args.duration}: expected a positive number of seconds")
    if not args.speed > 0:
        raise InputError(f"--speed {args.speed}: expected a positive time factor")
    if not args.fps > 0:
        raise InputError(f"--fps {args.fps}: expected a positive number of frames per second")
    if not args.window > 0:
        raise InputError(f"--window {args.window}: expected a positive number of seconds")
    from hdeem_watch.demo.nodes import demo_node

    node = demo_node(args.node)
    if args.sim_age is not None:
        from hdeem_watch.sim.age import check_pairs, parse_sim_age

        check_pairs(parse_sim_age(args.sim_age), node.layout.sensors)
    for flag, directory in (("--state-dir", args.state_dir), ("--report", args.report)):
        if directory is not None:
            _writable_directory(flag, directory)


def _writable_directory(flag: str, directory: str) -> None:
    """Create ``directory`` if needed and check it can be written, before the demo starts (not
    after a long run).

    Raises:
        InputError: it cannot be created or written.
    """
    path = Path(directory)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise InputError(f"{flag} {directory}: cannot create the directory ({error.strerror or error})") from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise InputError(f"{flag} {directory}: not writable by this user; expected a directory to write into")


def _run(args: argparse.Namespace) -> int:
    _check(args)
    if args.report:
        from hdeem_watch.report.style import MissingPlotting, pyplot

        try:
            pyplot()
        except MissingPlotting:
            print("hdeem-watch demo: error: --report needs matplotlib; pip install 'hdeem-watch[report]'",
                  file=sys.stderr)
            return 1
    if not args.headless and not _is_terminal():
        print(f"hdeem-watch demo: {why_no_tui()}; printing progress as text (--headless)", file=sys.stderr)
        args.headless = True
    from hdeem_watch.demo.daemon import DaemonFailed, DemoDaemon
    from hdeem_watch.demo.nodes import demo_node
    from hdeem_watch.demo.schedule import DemoSchedule

    node = demo_node(args.node)
    extra = ("--counters", args.counters, "--sim-node", node.name,
             *(("--sim-age", args.sim_age) if args.sim_age else ()))
    daemon = DemoDaemon(state_dir=args.state_dir, speed=args.speed, extra_args=extra)
    handled = (signal.SIGTERM, signal.SIGHUP)
    previous = {sig: signal.getsignal(sig) for sig in handled}

    def _terminate(signum: int, frame: FrameType | None) -> None:
        for sig in handled:  # a second signal must not interrupt the clean-up
            signal.signal(sig, signal.SIG_IGN)
        raise KeyboardInterrupt

    for sig in handled:
        signal.signal(sig, _terminate)
    try:
        if args.headless:
            kept = f" (daemon log: {daemon.log_path})" if daemon.log_kept else ""
            print(f"demo: starting a simulated node: {node.title}{kept}", flush=True)
        try:
            daemon.start()
        except DaemonFailed as error:
            print(f"hdeem-watch demo: {error}", file=sys.stderr)
            return 1
        if args.headless:
            return _headless(daemon.control_endpoint, args, node)
        return _tui(daemon.control_endpoint, args, DemoSchedule, node)
    except KeyboardInterrupt:
        return 130 if args.headless else 0
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if args.report:
            from hdeem_watch.report.demo import report_at_end

            report_at_end(daemon.state_dir, args.report)
        daemon.stop()


def why_no_tui() -> str:
    """Why the TUI cannot run here: a dumb terminal (``TERM=dumb``), or no terminal at all."""
    if sys.stdout.isatty() and os.environ.get("TERM", "") == "dumb":
        return "TERM=dumb: this terminal cannot draw the TUI"
    if os.environ.get("TERM", "") == "dumb":
        return "TERM=dumb and standard output is not a terminal"
    return "standard output is not a terminal"


def _is_terminal() -> bool:
    """Whether the TUI can run here (a terminal that is not 'dumb')."""
    return sys.stdout.isatty() and os.environ.get("TERM", "") != "dumb"


def _tui(control: str, args: argparse.Namespace, schedule_cls: Any, node: Any) -> int:
    from hdeem_watch.tui.app import HdeemWatchApp
    from hdeem_watch.tui.feed import FeedHub

    schedule = schedule_cls(control, speed=args.speed, node=node)
    hub = FeedHub([control], snapshot_hz=min(10.0, max(1.0, args.fps)))
    app = HdeemWatchApp(hub, fps=args.fps, window_s=args.window, exit_after_s=args.duration)
    schedule.start()
    try:
        app.run()
    finally:
        schedule.stop()
    return 0


def _headless(control: str, args: argparse.Namespace, node: Any) -> int:
    from hdeem_watch.demo.schedule import RUN_LENGTHS_S, DemoSchedule, ScheduleEvent
    from hdeem_watch.tui.feed import FeedHub
    from hdeem_watch.tui.headless import fit_width, print_progress, terminal_width

    ending = False

    def on_event(event: ScheduleEvent) -> None:
        if event.event == "error":
            print(f"error  run {event.index} {event.spec.kernel} {event.spec.threads}t: {event.detail}", flush=True)
        if event.event == "stop" and ending:
            window = (event.result or {}).get("window_s")
            length = f" after {window:.2f} s" if isinstance(window, float) else ""
            note = [f"note   the last run ({event.spec.kernel}-{event.spec.threads}t) was cut short",
                    f"by the end of the demo{length};", "it is calibrated like the others"]
            for line in fit_width(note, terminal_width()):
                print(line, flush=True)

    def at_end() -> None:
        nonlocal ending
        ending = True
        schedule.stop()

    intro = [
        f"demo: daemon at {control};",
        f"schedule: rounds of an idle run + 7 kernels at {'/'.join(node.thread_rounds)} threads,",
        f"runs of {'/'.join(f'{s:g}' for s in RUN_LENGTHS_S)} s; Ctrl-C stops.",
        "reading the lines:", "run = measured vs modelled DRAM energy",
        "(datasheet and calibrated currents, error in %);", "calib = the fit:",
        "'idd0 107.4->48.2 mA' = datasheet->calibrated current per device,",
        "'?' = not determined by the runs so far,", "loo = leave-one-out error,",
        "'sim incl. I/O' = the simulated node's truth the fit should reach", "(core = the DRAM core alone);",
        "idle = each pair's idle baseline.",
    ]
    for line in fit_width(intro, terminal_width()):
        print(line, flush=True)
    hub = FeedHub([control], snapshot_hz=4.0)
    hub.set_view(focus=-1, window_s=10.0, width=0)
    schedule = DemoSchedule(control, speed=args.speed, on_event=on_event, holdout=args.holdout, node=node)
    hub.start()
    schedule.start()
    start = time.monotonic()
    try:
        print_progress(hub, duration_s=args.duration, at_end=at_end)
    except KeyboardInterrupt:
        print("demo: interrupted; stopping the run in progress, the feed and the sim daemon (about a second)",
              file=sys.stderr, flush=True)
        raise
    finally:
        schedule.stop()
        hub.stop()
    calib = hub.snapshots()[0].calib
    from hdeem_watch.cli.numbers import counted

    print(f"demo: done after {time.monotonic() - start:.0f} s, {counted(schedule.completed, 'run')} "
          f"(the calibration holds {calib.n_runs})", flush=True)
    print(alarm_summary(calib.alarms), flush=True)
    return 0


def alarm_summary(alarms: Any) -> str:
    """The demo's last line about aging: every alarm of the run, or that there was none.

    Example:
        >>> from hdeem_watch.tui.snapshot import AlarmView
        >>> alarm_summary(())
        'demo: no drift alarm on any DIMM pair'
        >>> alarm_summary((AlarmView("DDR_CD", "energy", "residual-cusum", "up", 12.4, 10.0, 0),))
        'demo: 1 drift alarm: DDR_CD energy drifts up (residual-cusum 12.4 > 10)'
    """
    from hdeem_watch.tui.group_views import alarm_text

    if not alarms:
        return "demo: no drift alarm on any DIMM pair"
    return f"demo: {len(alarms)} drift alarm{'s' if len(alarms) > 1 else ''}: " + "; ".join(alarm_text(a) for a in alarms)
