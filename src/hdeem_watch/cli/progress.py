"""A one-line progress bar on stderr when stderr is a terminal, silent everywhere else.

Long model runs (``model stats`` on a multi-GB trace, ``--emit-drampower``) show how far they are;
a pipe, a file or a batch job's log gets nothing.

Example::

    progress = Progress(sys.stderr, "simulating")
    simulate_trace(spec, path, fmt, progress=progress.update)   # calls update(done, total)
    progress.clear()
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TextIO

#: Width of the bar in characters.
BAR_CHARS = 30
#: Fewest seconds between two repaints (a fast loop does not flood the terminal).
MIN_REPAINT_S = 0.1


class Progress:
    """A progress bar for one phase of work (``label``), repainted in place.

    Args:
        stream: where to draw (usually ``sys.stderr``); nothing is drawn unless it is a terminal.
        label: what is being done, shown right of the bar.
        clock: monotonic seconds (injected for tests).
    """

    def __init__(self, stream: TextIO, label: str, *, clock: Callable[[], float] = time.monotonic) -> None:
        self.stream = stream
        self.label = label
        self.enabled = stream.isatty()
        self._clock = clock
        self._shown_at = -MIN_REPAINT_S
        self._drawn = False

    def update(self, done: int, total: int) -> None:
        """Show ``done`` of ``total`` (repaints at most every :data:`MIN_REPAINT_S`, and at the end)."""
        if not self.enabled:
            return
        now = self._clock()
        if done < total and now - self._shown_at < MIN_REPAINT_S:
            return
        self._shown_at = now
        filled = int(BAR_CHARS * done / total) if total > 0 else BAR_CHARS
        bar = "#" * filled + "-" * (BAR_CHARS - filled)
        percent = 100.0 * done / total if total > 0 else 100.0
        self.stream.write(f"\r[{bar}] {percent:5.1f} % {self.label}")
        self.stream.flush()
        self._drawn = True

    def phase(self, label: str) -> None:
        """Start the next phase of the same job under a new label."""
        self.label = label
        self._shown_at = -MIN_REPAINT_S

    def clear(self) -> None:
        """Erase the bar (before printing results or an error)."""
        if self._drawn:
            self.stream.write("\r\x1b[K")
            self.stream.flush()
            self._drawn = False
