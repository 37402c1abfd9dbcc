"""Plain-text progress for terminals without a TUI (``--headless``, ``TERM=dumb``, CI).

:class:`ProgressPrinter` reads the same snapshots the TUI paints and turns what changed into
lines: the connection state (with the reason while not live), each new finished run (measured vs
modelled energy), each new calibration (errors and the currents against the simulation's truth),
and the live DRAM power every few seconds once there is a value. Runs the daemon had stored before
the printer connected are summed up in one line, not replayed as new. Every line fits ``width``
columns: a long record continues on indented lines, breaking between its fields. The printer is
pure (it returns lines); :func:`print_progress` is the loop that prints them.

Example:
    >>> from hdeem_watch.tui.snapshot import HealthView, NodeSnapshot
    >>> printer = ProgressPrinter(power_every_s=0)
    >>> health = HealthView(state="connecting", endpoint="ipc:///x/control.sock", detail="no reply within 1 s")
    >>> printer.lines(NodeSnapshot(node="?", built_mono_ns=1, window_s=60, health=health), now_s=0.0)
    ['state  ipc:///x/control.sock connecting  (no reply within 1 s)']
"""

from __future__ import annotations

import math
import shutil
import statistics
import sys
import textwrap
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, TextIO

from hdeem_watch.dram.kernels import HOLDOUT_KERNELS
from hdeem_watch.tui.group_views import alarm_text, is_drift
from hdeem_watch.tui.snapshot import CalibView, NodeSnapshot, RunView
from hdeem_watch.tui.widgets.fmt import percent

if TYPE_CHECKING:
    from hdeem_watch.tui.feed import FeedHub

#: Continuation lines of a long record start with this.
INDENT = " " * 7
#: Width when the terminal's is unknown (output to a pipe or file).
DEFAULT_WIDTH = 100
#: In print_progress: give up on a node that sent nothing at all for this long.
GIVE_UP_S = 10.0


def fit_width(parts: Sequence[str], width: int) -> list[str]:
    """Join ``parts`` with two spaces into lines of at most ``width`` characters, breaking between
    parts; continuation lines are indented; a part too long for a line of its own is wrapped.

    >>> fit_width(["run    copy-24t", "measured 1.00 J", "model 2.00 J"], 32)
    ['run    copy-24t  measured 1.00 J', '       model 2.00 J']
    """
    width = max(width, len(INDENT) + 20)
    lines: list[str] = []
    line = ""
    for part in parts:
        candidate = f"{line}  {part}" if line else part
        if len(candidate) <= width:
            line = candidate
            continue
        if line.strip():
            lines.append(line)
        prefix = INDENT if lines else ""
        chunks = textwrap.wrap(part, width - len(INDENT), break_on_hyphens=False) or [""]
        for chunk in chunks[:-1]:
            lines.append(prefix + chunk)
            prefix = INDENT
        line = prefix + chunks[-1]
    if line:
        lines.append(line)
    return lines


def run_parts(run: RunView) -> list[str]:
    """One finished run, as fields."""
    return [
        f"run    {run.name:<14.14} {run.kernel:<9} {run.threads:>2}t {run.duration_s:5.2f} s",
        f"measured {_j(run.measured_j)}",
        f"model datasheet {_j(run.model_datasheet_j)} ({percent(run.error_datasheet).strip()})",
        f"calibrated {_j(run.model_calibrated_j)} ({percent(run.error_calibrated).strip()})",
    ]


def run_line(run: RunView) -> str:
    """One finished run on one line."""
    return "  ".join(run_parts(run))


def calib_parts(calib: CalibView) -> list[str]:
    """One calibration state as fields (currents in mA per device; ``sim`` = the simulation's hidden
    truth that a fit can recover, incl. I/O energy and sensor offsets; ``core`` = its core truth).
    Errors are "–" while the fit is not determined (fewer runs than unknowns)."""
    determined = calib.determined
    after = _pct(calib.error_after) if determined else "– (not determined yet)"
    parts = [
        f"calib  {calib.n_runs} {_runs(calib.n_runs)}",
        f"error before {_pct(calib.error_before)} after {after}" + (f" loo {_pct(calib.error_loo)}" if determined else ""),
    ]
    for c in calib.currents:
        item = f"{c.name} {c.datasheet_a * 1e3:.1f}->{c.calibrated_a * 1e3:.1f} mA"
        core = getattr(c, "truth_core_a", math.nan)
        if math.isfinite(c.truth_a) and isinstance(core, float) and math.isfinite(core):
            item += f" (sim incl. I/O {c.truth_a * 1e3:.1f}, core {core * 1e3:.1f})"
        elif math.isfinite(c.truth_a):
            item += f" (sim {c.truth_a * 1e3:.1f})"
        if not c.identifiable:
            item += "?"
        parts.append(item)
    if calib.suggested_next:
        parts.append(f"suggested next run: {calib.suggested_next}")
    return parts


def calib_line(calib: CalibView) -> str:
    """One calibration state on one line."""
    return "  ".join(calib_parts(calib))


def power_parts(snapshot: NodeSnapshot) -> list[str]:
    """Live power of the DRAM channels (and state), as fields."""
    health = snapshot.health
    values = [
        f"{c.name} {c.power_w:.2f} W" if math.isfinite(c.power_w) else f"{c.name} –"
        for c in snapshot.channels
        if c.kind == "dram"
    ] or ["(no samples yet)"]
    return [f"power  {values[0]}", *values[1:], f"[{health.state}, gaps {health.gaps}]"]


def power_line(snapshot: NodeSnapshot) -> str:
    """Live power of the DRAM channels on one line."""
    return "  ".join(power_parts(snapshot))


def baseline_parts(snapshot: NodeSnapshot) -> list[str]:
    """The idle baseline of each DRAM channel (W, and how it was measured), as fields; empty
    while none is known."""
    known = [c for c in snapshot.channels if c.kind == "dram" and math.isfinite(c.baseline_w)]
    if not known:
        return []
    values = [f"{c.name} {c.baseline_w:.2f} W" for c in known]
    origin = sorted({c.baseline_origin for c in known if c.baseline_origin})
    return [f"idle   {values[0]}", *values[1:], f"(baselines: {', '.join(origin) or 'measured'})"]


def _has_power(snapshot: NodeSnapshot) -> bool:
    return any(c.kind == "dram" and math.isfinite(c.power_w) for c in snapshot.channels)


def _j(value: float) -> str:
    return f"{value:.2f} J" if math.isfinite(value) else "– J"


def _pct(value: float) -> str:
    return f"{value * 100:.1f}%" if math.isfinite(value) else "–"


def _runs(n: int) -> str:
    return "run" if n == 1 else "runs"


class ProgressPrinter:
    """Turns successive snapshots of one node into progress lines.

    Args:
        power_every_s: how often to print a power line (0: every call), once there is a value.
        width: the longest line (the terminal's width).
    """

    def __init__(self, power_every_s: float = 5.0, width: int = 10_000) -> None:
        self.power_every_s = power_every_s
        self.width = width
        self._seen_runs: set[str] = set()
        self._history_told = False
        self._calib_key: tuple[object, ...] | None = None
        self._seen_alarms: set[tuple[str, str, str, int]] = set()
        self._state: tuple[str, str] = ("", "")
        self._last_power_s = -math.inf
        self._baselines: tuple[float, ...] = ()
        #: hold-out runs seen: (calibrated error, datasheet error) of each
        self.holdout: list[tuple[float, float]] = []

    def holdout_line(self) -> str | None:
        """``holdout: N runs, median error X %, worst Y % (datasheet …)``: the hold-out runs
        (:data:`hdeem_watch.dram.kernels.HOLDOUT_KERNELS`, never fitted) predicted with the fit from
        before each, against their measured energy; None before the first."""
        return holdout_text(self.holdout)

    def _note_holdout(self, run: RunView) -> None:
        if run.kernel in HOLDOUT_KERNELS and not run.running and not run.history:
            cal, ds = run.error_calibrated, run.error_datasheet
            if math.isfinite(cal) and math.isfinite(ds):
                self.holdout.append((abs(cal), abs(ds)))

    def lines(self, snapshot: NodeSnapshot, now_s: float) -> list[str]:
        """New lines for ``snapshot`` at ``now_s`` (seconds on any monotonic clock)."""
        out: list[str] = []
        health = snapshot.health
        state = (health.state, health.detail if health.state != "live" else "")
        if state != self._state:
            name = snapshot.node if snapshot.node != "?" else health.endpoint
            detail = [f"({state[1]})"] if state[1] else []
            out += fit_width([f"state  {name} {health.state}", *detail], self.width)
            self._state = state
        history = [run for run in snapshot.runs if run.history and run.run_id not in self._seen_runs]
        if history and not self._history_told:
            self._history_told = True
            earlier = max(len(history), snapshot.runs_total - sum(not r.history for r in snapshot.runs))
            out += fit_width([f"runs   {earlier} earlier {_runs(earlier)} stored by the daemon (not listed; "
                              f"the newest: {history[-1].name})"], self.width)
        for run in snapshot.runs:
            if run.run_id not in self._seen_runs:
                self._seen_runs.add(run.run_id)
                self._note_holdout(run)
                if not run.history:
                    out += fit_width(run_parts(run), self.width)
        calib = snapshot.calib
        key = (calib.n_runs, calib.error_after, tuple(c.calibrated_a for c in calib.currents))
        if calib.currents and key != self._calib_key:
            self._calib_key = key
            out += fit_width(calib_parts(calib), self.width)
        for alarm in calib.alarms:
            if alarm.key not in self._seen_alarms:
                self._seen_alarms.add(alarm.key)
                out += fit_width([f"{'drift ' if is_drift(alarm) else 'outlr '} {alarm_text(alarm)}"], self.width)
        baselines = tuple(round(c.baseline_w, 2) for c in snapshot.channels if c.kind == "dram")
        if baselines != self._baselines and (parts := baseline_parts(snapshot)):
            self._baselines = baselines
            out += fit_width(parts, self.width)
        if _has_power(snapshot) and now_s - self._last_power_s >= self.power_every_s:
            self._last_power_s = now_s
            out += fit_width(power_parts(snapshot), self.width)
        return out


def holdout_text(errors: Sequence[tuple[float, float]]) -> str | None:
    """The hold-out summary line of ``(|calibrated error|, |datasheet error|)`` pairs (None: none).

    >>> holdout_text([(0.02, 0.4), (0.05, 0.6), (0.01, 0.5)])
    'holdout: 3 runs, median error 2.0 %, worst 5.0 % (datasheet: median 50.0 %, worst 60.0 %)'
    """
    if not errors:
        return None
    cal = sorted(e for e, _ in errors)
    ds = sorted(d for _, d in errors)
    return (f"holdout: {len(cal)} {_runs(len(cal))}, median error {100 * statistics.median(cal):.1f} %, "
            f"worst {100 * cal[-1]:.1f} % (datasheet: median {100 * statistics.median(ds):.1f} %, "
            f"worst {100 * ds[-1]:.1f} %)")


def terminal_width() -> int:
    """The terminal's width (``$COLUMNS`` or the tty's), :data:`DEFAULT_WIDTH` when unknown."""
    return shutil.get_terminal_size((DEFAULT_WIDTH, 24)).columns


def silent_nodes(snapshots: Sequence[NodeSnapshot]) -> list[NodeSnapshot]:
    """The nodes from which nothing at all has arrived on the stream."""
    return [s for s in snapshots if not math.isfinite(s.health.last_rx_age_s)]


def print_progress(
    hub: FeedHub,
    *,
    duration_s: float | None = None,
    out: TextIO | None = None,
    period_s: float = 0.5,
    power_every_s: float = 5.0,
    width: int | None = None,
    give_up_s: float | None = GIVE_UP_S,
    at_end: Callable[[], None] | None = None,
) -> int:
    """Print the progress of every node of ``hub`` until ``duration_s`` (None: until interrupted),
    or until ``give_up_s`` have passed with a node that sent nothing (see :func:`silent_nodes`).

    Lines are prefixed with the node's name when there are several nodes, and fit ``width``
    (default: the terminal's). ``at_end`` (e.g. stopping a benchmark schedule, which lets its run
    in progress finish) is called when the duration is over; what happened until it returned is
    printed before this returns, so no finished run goes unprinted. Returns the number of lines
    printed.
    """
    stream = out if out is not None else sys.stdout
    columns = width if width is not None else terminal_width()
    printers = [ProgressPrinter(power_every_s=power_every_s) for _ in hub.feeds]
    start = time.monotonic()
    count = 0

    def print_new() -> list[Any]:
        nonlocal count
        now = time.monotonic() - start
        snapshots = hub.snapshots()
        for printer, snapshot in zip(printers, snapshots):
            prefix = f"[{snapshot.node}] " if len(printers) > 1 else ""
            printer.width = columns - len(prefix)
            for line in printer.lines(snapshot, now):
                print(prefix + line, file=stream, flush=True)
                count += 1
        return snapshots

    while duration_s is None or time.monotonic() - start < duration_s:
        time.sleep(period_s)
        snapshots = print_new()
        if give_up_s is not None and time.monotonic() - start >= give_up_s and silent_nodes(snapshots):
            return count
    if at_end is not None:
        at_end()
        time.sleep(period_s)  # the last runs' records reach the snapshots
        print_new()
    for printer, snapshot in zip(printers, hub.snapshots()):
        line = printer.holdout_line()
        if line is not None:
            prefix = f"[{snapshot.node}] " if len(printers) > 1 else ""
            print(prefix + line, file=stream, flush=True)
            count += 1
    return count
