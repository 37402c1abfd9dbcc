"""Plain-text progress for terminals without a TUI (``hdeem-watch demo --headless``, CI).

:class:`ProgressPrinter` reads the same snapshots the TUI paints and turns what changed into
lines: each finished run (measured vs modelled energy), each new calibration (errors and the
currents against the simulation's truth), and the live DRAM power every few seconds. The printer
is pure (it returns lines); :func:`print_progress` is the loop that prints them.

Example:
    >>> from hdeem_watch.tui.snapshot import NodeSnapshot
    >>> printer = ProgressPrinter(power_every_s=0)
    >>> printer.lines(NodeSnapshot(node="n1", built_mono_ns=1, window_s=60), now_s=0.0)
    ['state  n1 connecting']
"""

from __future__ import annotations

import math
import sys
import time
from typing import TYPE_CHECKING, TextIO

from hdeem_watch.tui.snapshot import CalibView, NodeSnapshot, RunView
from hdeem_watch.tui.widgets.fmt import percent

if TYPE_CHECKING:
    from hdeem_watch.tui.feed import FeedHub


def run_line(run: RunView) -> str:
    """One finished run."""
    return (
        f"run    {run.name:<14.14} {run.kernel:<9} {run.threads:>2}t {run.duration_s:5.2f} s  "
        f"measured {_j(run.measured_j)}  model datasheet {_j(run.model_datasheet_j)} ({percent(run.error_datasheet).strip()})  "
        f"calibrated {_j(run.model_calibrated_j)} ({percent(run.error_calibrated).strip()})"
    )


def calib_line(calib: CalibView) -> str:
    """One calibration state (currents in mA per device; ``sim`` = the simulation's hidden truth that a
    fit can recover, incl. I/O energy and sensor offsets; ``core`` = its core truth)."""
    parts = [
        f"calib  {calib.n_runs} runs  error before {_pct(calib.error_before)} after {_pct(calib.error_after)} "
        f"loo {_pct(calib.error_loo)}"
    ]
    for c in calib.currents:
        item = f"{c.name} {c.datasheet_a * 1e3:.1f}->{c.calibrated_a * 1e3:.1f}"
        core = getattr(c, "truth_core_a", math.nan)
        if math.isfinite(c.truth_a) and isinstance(core, float) and math.isfinite(core):
            item += f" (sim incl. I/O {c.truth_a * 1e3:.1f}, core {core * 1e3:.1f})"
        elif math.isfinite(c.truth_a):
            item += f" (sim {c.truth_a * 1e3:.1f})"
        if not c.identifiable:
            item += "?"
        parts.append(item)
    if calib.suggested_next:
        parts.append(f"next: {calib.suggested_next}")
    return "  ".join(parts)


def power_line(snapshot: NodeSnapshot) -> str:
    """Live power of the DRAM channels (and state)."""
    health = snapshot.health
    values = "  ".join(
        f"{c.name} {c.power_w:.2f} W" if math.isfinite(c.power_w) else f"{c.name} –"
        for c in snapshot.channels
        if c.kind == "dram"
    )
    return f"power  {values or '(no samples yet)'}  [{health.state}, gaps {health.gaps}]"


def _j(value: float) -> str:
    return f"{value:.2f} J" if math.isfinite(value) else "– J"


def _pct(value: float) -> str:
    return f"{value * 100:.1f}%" if math.isfinite(value) else "–"


class ProgressPrinter:
    """Turns successive snapshots of one node into progress lines.

    Args:
        power_every_s: how often to print a power line (0: every call).
    """

    def __init__(self, power_every_s: float = 5.0) -> None:
        self.power_every_s = power_every_s
        self._seen_runs: set[str] = set()
        self._calib_key: tuple[object, ...] | None = None
        self._state = ""
        self._last_power_s = -math.inf

    def lines(self, snapshot: NodeSnapshot, now_s: float) -> list[str]:
        """New lines for ``snapshot`` at ``now_s`` (seconds on any monotonic clock)."""
        out: list[str] = []
        state = snapshot.health.state
        if state != self._state:
            detail = f" ({snapshot.health.detail})" if snapshot.health.detail and state != "live" else ""
            out.append(f"state  {snapshot.node} {state}{detail}")
            self._state = state
        for run in snapshot.runs:
            if run.run_id not in self._seen_runs:
                self._seen_runs.add(run.run_id)
                out.append(run_line(run))
        calib = snapshot.calib
        key = (calib.n_runs, calib.error_after, tuple(c.calibrated_a for c in calib.currents))
        if calib.currents and key != self._calib_key:
            self._calib_key = key
            out.append(calib_line(calib))
        if snapshot.channels and now_s - self._last_power_s >= self.power_every_s:
            self._last_power_s = now_s
            out.append(power_line(snapshot))
        return out


def print_progress(
    hub: FeedHub,
    *,
    duration_s: float | None = None,
    out: TextIO | None = None,
    period_s: float = 0.5,
    power_every_s: float = 5.0,
) -> int:
    """Print the progress of every node of ``hub`` until ``duration_s`` (None: until interrupted).

    Lines are prefixed with the node's name when there are several nodes. Returns the number of
    lines printed.
    """
    stream = out if out is not None else sys.stdout
    printers = [ProgressPrinter(power_every_s=power_every_s) for _ in hub.feeds]
    start = time.monotonic()
    count = 0
    while duration_s is None or time.monotonic() - start < duration_s:
        time.sleep(period_s)
        now = time.monotonic() - start
        for printer, snapshot in zip(printers, hub.snapshots()):
            prefix = f"[{snapshot.node}] " if len(printers) > 1 else ""
            for line in printer.lines(snapshot, now):
                print(prefix + line, file=stream, flush=True)
                count += 1
    return count
