"""The Textual app: paints the newest snapshots at a fixed rate; keys for pause, node, zoom,
baseline, stopping the run in progress, and help.

The app never reads sockets. A :class:`~hdeem_watch.tui.provider.Provider` (live:
:class:`~hdeem_watch.tui.feed.FeedHub`) builds immutable snapshots in the background; a timer at
``fps`` takes the newest and repaints every widget inside ``batch_update()`` (memray's live-TUI
pattern). Pause stops repainting the data (the health bar keeps saying ``PAUSED``), so a paused
screen never looks live, and a feed that stops producing shows ``UI STALLED``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import ClassVar

from textual.app import App, ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import Horizontal, Vertical
from textual.screen import ModalScreen, Screen
from textual.widgets import Static

from hdeem_watch.tui.provider import Provider
from hdeem_watch.tui.snapshot import NodeSnapshot, jobs_line
from hdeem_watch.tui.widgets import CalibPanel, ChannelTable, GroupsPanel, HealthBar, PowerPlots, RunsPanel
from hdeem_watch.tui.widgets.lines import LinesWidget

#: Plot windows the +/- keys step through, in seconds.
WINDOWS_S = (5.0, 10.0, 30.0, 60.0, 120.0, 300.0, 600.0)
#: A snapshot older than this means its feed stopped producing.
STALLED_AFTER_S = 3.0
#: Seconds of the idle baseline measurement the ``b`` key asks for.
BASELINE_SECONDS = 10.0

#: Seconds a control reply stays on the key line.
NOTICE_S = 8.0

KEYS_LINE = " p pause  n/N/tab node  +/- zoom  b baseline  s stop  g pairs  ? help  q quit"

HELP_TEXT = f"""[b]hdeem-watch[/b]: live DRAM power and model calibration

[b]p[/b]          pause / resume painting (data keeps arriving)
[b]n[/b] [b]tab[/b]      next node   [b]N[/b] [b]shift+tab[/b]  previous node
[b]+[/b] [b]-[/b]        zoom the time window ({"/".join(f"{w:g}" for w in WINDOWS_S)} s)
[b]b[/b]          measure this node's idle baseline ({BASELINE_SECONDS:g} s, between runs)
[b]s[/b]          stop (abort) the run in progress, e.g. to let [b]b[/b] measure
[b]g[/b]          per-pair fits   [b]?[/b] this help   [b]q[/b] [b]ctrl+c[/b] quit

[b]above[/b]: power over the idle baseline; – where the baseline is not
  idle (CPU/BLADE in an idle run: its kernel keeps the CPUs busy).
Plots: min/max envelope per column; left: name, range lo–hi in W.
[b]ds %[/b] / [b]cal %[/b]: a run's model error, datasheet / calibrated currents.
[b]error[/b] before/after the fit, mean over runs; [b]loo[/b]: each run predicted
  without it; – until there are more runs than unknowns.
Currents in mA per device; id ✓ = determined by the runs so far.
sim: the simulated node's hidden true currents.
suggested run: the calibrator's pick for the next run (not a plan).
STALE: no message for 3 s.  RECONNECTING: daemon unreachable.
gaps: messages lost on the wire (from sequence numbers).
Press any key to close."""


class HelpScreen(ModalScreen[None]):
    """Key help; any key closes it."""

    def compose(self) -> ComposeResult:
        yield Static(HELP_TEXT)

    def on_key(self) -> None:
        self.dismiss()


class GroupsScreen(Screen[None]):
    """The per-pair calibration view of the focused node (repainted with the app's frames)."""

    BINDINGS: ClassVar[list[BindingType]] = [Binding("g,escape", "app.pop_screen", "back")]

    def compose(self) -> ComposeResult:
        yield HealthBar()
        yield GroupsPanel()
        yield Static(" g/esc back  n/N/tab node  p pause  q quit", id="keys")


class HdeemWatchApp(App[int]):
    """Live view of one or more hdeem-watch daemons.

    Args:
        provider: the snapshot source (started on mount, stopped on exit).
        fps: repaint rate (frames per second).
        clock: monotonic clock in ns (injectable for deterministic screenshots).
        window_s: the initial plot window (snapped to one of :data:`WINDOWS_S`).
        exit_after_s: quit by itself after this many seconds (None: run until ``q``).
        baseline_s: length of the idle baseline measurement the ``b`` key asks for.

    Example:
        >>> from hdeem_watch.tui.provider import StaticProvider
        >>> from hdeem_watch.tui.snapshot import NodeSnapshot
        >>> app = HdeemWatchApp(StaticProvider([NodeSnapshot(node="n1", built_mono_ns=1, window_s=60)]))
    """

    CSS_PATH = Path(__file__).with_name("app.tcss")
    TITLE = "hdeem-watch"
    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("q", "quit", "quit"),
        Binding("ctrl+c", "quit", "quit", priority=True, show=False),
        Binding("p", "pause", "pause"),
        Binding("n,tab", "node(1)", "next node", priority=True),
        Binding("N,shift+tab", "node(-1)", "previous node", priority=True),
        Binding("plus,equals_sign", "zoom(-1)", "zoom in"),
        Binding("minus,underscore", "zoom(1)", "zoom out"),
        Binding("b", "baseline", "baseline"),
        Binding("s", "stop_run", "stop run"),
        Binding("g", "groups", "per-pair calibration"),
        Binding("question_mark", "help", "help"),
    ]

    def __init__(
        self,
        provider: Provider,
        *,
        fps: float = 10.0,
        clock: Callable[[], int] = time.monotonic_ns,
        window_s: float = 60.0,
        exit_after_s: float | None = None,
        baseline_s: float = BASELINE_SECONDS,
    ) -> None:
        super().__init__()
        self.provider = provider
        self.fps = max(0.2, float(fps))
        self._clock = clock
        self.window_s = min(WINDOWS_S, key=lambda w: abs(w - window_s))
        self.focus_index = 0
        self.paused = False
        self.frames = 0
        self._n_nodes = max(1, len(provider.snapshots()))
        self._exit_after_s = exit_after_s
        self.baseline_s = baseline_s
        self._shown_once = False
        self._feed_notice = ""  # the last notice the focused feed reported
        self._notice = ""  # what the key line shows until _notice_until
        self._notice_until = 0
        self._keys_text = KEYS_LINE
        self._job_text: str | None = None  # the current-job line shown (None: not painted yet)

    def compose(self) -> ComposeResult:
        yield HealthBar()
        with Horizontal(id="body"):
            with Vertical(id="left"):
                yield ChannelTable()
                yield PowerPlots()
            with Vertical(id="right"):
                yield CalibPanel()
                yield RunsPanel()
        job_line = Static("", id="job")  # the SLURM jobs open on the focused node (hidden when none)
        job_line.display = False
        yield job_line
        yield Static(KEYS_LINE, id="keys")

    def on_mount(self) -> None:
        self.provider.start()
        self._push_view()
        self.call_after_refresh(self.paint)
        self.set_interval(1.0 / self.fps, self.paint)
        if self._exit_after_s is not None:
            self.set_timer(self._exit_after_s, self.exit)

    def on_unmount(self) -> None:
        self.provider.stop()

    def _push_view(self) -> None:
        width = self.query_one(PowerPlots).data_columns()
        self.provider.set_view(focus=self.focus_index, window_s=self.window_s, width=width)

    def paint(self) -> None:
        """Repaint from the newest snapshots (one frame)."""
        if not self.is_running:  # shutting down: the interval may fire once more after the widgets went
            return
        snapshots = self.provider.snapshots()
        if not snapshots:
            return
        self._n_nodes = len(snapshots)
        self.focus_index %= self._n_nodes
        self._push_view()
        snap = snapshots[self.focus_index]
        age_s = (self._clock() - snap.built_mono_ns) / 1e9
        stalled = age_s > STALLED_AFTER_S
        with self.batch_update():
            self.query_one(HealthBar).show(
                snapshots, self.focus_index, paused=self.paused, stalled=stalled, window_s=self.window_s
            )
            stale = stalled or snap.health.state in ("stale", "reconnecting")
            if stale != self.screen.has_class("-stale"):
                self.screen.set_class(stale, "-stale")
                for widget in self.query(LinesWidget):
                    widget.restyle()
            if not self.paused or not self._shown_once:
                self._shown_once = self.query_one(PowerPlots).size.width > 0
                self.query_one(ChannelTable).show(snap)
                self.query_one(PowerPlots).show(snap)
                self.query_one(CalibPanel).show(snap.calib)
                self.query_one(RunsPanel).show(snap)
                if isinstance(self.screen, GroupsScreen):
                    self.screen.query_one(HealthBar).show(snapshots, self.focus_index, paused=self.paused,
                                                          stalled=stalled, window_s=self.window_s)
                    self.screen.query_one(GroupsPanel).show(snap.calib)
            self._show_jobs(snap)
            self._show_notice(snap.health.notice)
        self.frames += 1

    @property
    def key_line(self) -> str:
        """What the bottom line shows now: the key hints, or a fresh control reply."""
        return self._keys_text

    def _show_jobs(self, snap: NodeSnapshot) -> None:
        """The current-job line: the SLURM jobs open on the focused node; no line without one."""
        text = jobs_line(snap.jobs)
        if text != self._job_text:
            self._job_text = text
            line = self.query_one("#job", Static)
            if text:
                line.update(text)
            if line.display != bool(text):
                line.display = bool(text)

    def _show_notice(self, feed_notice: str) -> None:
        """The newest notice — a control reply from the feed, or the app's own — replaces the key
        line for :data:`NOTICE_S` seconds."""
        now = self._clock()
        if feed_notice != self._feed_notice:
            self._feed_notice = feed_notice
            if feed_notice:
                self._flash(feed_notice)
        text = f" {self._notice}" if self._notice and now < self._notice_until else KEYS_LINE
        keys = self.query_one("#keys", Static)
        if text != self._keys_text:
            self._keys_text = text
            keys.update(text)
            keys.set_class(text != KEYS_LINE, "-notice")

    def _flash(self, notice: str) -> None:
        """Show ``notice`` on the key line for :data:`NOTICE_S` seconds."""
        self._notice = notice
        self._notice_until = self._clock() + int(NOTICE_S * 1e9)

    # ------------------------------------------------------------------ actions

    def action_pause(self) -> None:
        """Toggle pause."""
        self.paused = not self.paused
        self.paint()

    def action_node(self, step: int) -> None:
        """Focus the next/previous node."""
        self.focus_index = (self.focus_index + step) % self._n_nodes
        self.paint()

    def action_zoom(self, step: int) -> None:
        """Step the time window through :data:`WINDOWS_S`."""
        i = WINDOWS_S.index(self.window_s)
        self.window_s = WINDOWS_S[max(0, min(len(WINDOWS_S) - 1, i + step))]
        self._push_view()
        self.paint()

    def action_baseline(self) -> None:
        """Ask the focused node's daemon to measure its idle baseline."""
        self.provider.request(self.focus_index, "baseline.measure", {"seconds": self.baseline_s})
        self.paint()  # the key line says "sent" now and shows the daemon's reply when it comes

    def action_stop_run(self) -> None:
        """Ask the focused node's daemon to stop (abort: not calibrated) the run in progress."""
        snapshots = self.provider.snapshots()
        run = snapshots[self.focus_index % len(snapshots)].current_run if snapshots else None
        if run is None:
            self._flash("s: no run in progress")
        else:
            self.provider.request(self.focus_index, "run.stop", {"run_id": run.run_id, "abort": True})
        self.paint()

    def action_groups(self) -> None:
        """Show the per-pair calibration view."""
        self.push_screen(GroupsScreen())
        self.call_after_refresh(self.paint)

    def action_help(self) -> None:
        """Show the key help."""
        self.push_screen(HelpScreen())
