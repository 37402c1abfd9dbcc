"""A one-line progress bar on stderr when stderr is a terminal, silent everywhere else.

Long model runs (``model stats`` on a multi-GB trace, ``--emit-drampower``) show how far they are;
a pipe, a file or a batch job's log gets nothing.

Example::

    progress = Progress(sys.stderr)
    simulate_trace(spec, path, fmt, progress=progress.callback())   # update(phase, done, total)
    progress.clear()
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TextIO

from hdeem_watch.dram.progress import ProgressCallback

#: Width of the bar in characters.
BAR_CHARS = 30
#: Fewest seconds between two repaints (a fast loop does not flood the terminal).
MIN_REPAINT_S = 0.1


class Progress:
    """A progress bar for the phases of a job, repainted in place; its :meth:`update` is a
    :data:`hdeem_watch.dram.progress.ProgressCallback`.

    Args:
        stream: where to draw (usually ``sys.stderr``); nothing is drawn unless it is a terminal.
        clock: monotonic seconds (injected for tests).
    """

    def __init__(self, stream: TextIO, *, clock: Callable[[], float] = time.monotonic) -> None:
        self.stream = stream
        self.label = ""
        self.enabled = stream.isatty()
        self._clock = clock
        self._shown_at = -MIN_REPAINT_S
        self._drawn = False

    def update(self, phase: str, done: int, total: int) -> None:
        """Show ``done`` of ``total`` of ``phase`` (repaints at most every :data:`MIN_REPAINT_S`,
        and always at a phase's start and end)."""
        if not self.enabled:
            return
        now = self._clock()
        if phase != self.label:
            self.label = phase
        elif done < total and now - self._shown_at < MIN_REPAINT_S:
            return
        self._shown_at = now
        filled = int(BAR_CHARS * done / total) if total > 0 else BAR_CHARS
        bar = "#" * filled + "-" * (BAR_CHARS - filled)
        percent = 100.0 * done / total if total > 0 else 100.0
        self.stream.write(f"\r[{bar}] {percent:5.1f} % {self.label:<40.40}")
        self.stream.flush()
        self._drawn = True

    def callback(self) -> ProgressCallback | None:
        """:meth:`update` on a terminal, else None (so the model skips its progress bookkeeping)."""
        return self.update if self.enabled else None

    def clear(self) -> None:
        """Erase the bar (before printing results or an error)."""
        if self._drawn:
            self.stream.write("\r\x1b[K")
            self.stream.flush()
            self._drawn = False
