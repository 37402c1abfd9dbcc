"""The MetricQ source's state: what it is connected to and what went through it.

The command logs :meth:`SourceStatus.line` every ``status_interval_s`` and writes
:meth:`SourceStatus.to_dict` as JSON to the status file (atomically) when one is configured.

Example:
    >>> s = SourceStatus()
    >>> s.broker, s.daemon
    ('connecting', 'waiting')
    >>> s.points_sent += 5
    >>> s.line()
    'broker connecting, daemon waiting: 0 messages, 5 points sent, 0 waiting, 0 dropped, 0 reconnects'
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

#: States of the MetricQ side.
BROKER_STATES = ("connecting", "connected", "down", "stopped")
#: States of the daemon side.
DAEMON_STATES = ("waiting", "streaming", "silent")


@dataclass
class SourceStatus:
    """Counters and states (all counts since the source started).

    Attributes:
        broker: ``connecting`` (first attempt), ``connected``, ``down`` (retrying), ``stopped``.
        daemon: ``waiting`` (no message yet), ``streaming``, ``silent`` (nothing for a while).
        messages: stream messages read.
        points_in: data points made from them.
        points_sent: data points published to MetricQ.
        points_waiting: data points buffered, not yet published.
        points_dropped: data points dropped because the buffer was full (broker away too long).
        out_of_order: data points left out because their time was not after the previous one.
        stream_gaps: stream messages the daemon sent that this source missed (sequence jumps).
        daemon_restarts: daemon restarts seen (sequence numbers going back).
        broker_connects: successful connections to MetricQ (1 + reconnects).
        broker_failures: failed connection or publish attempts.
        metrics: metrics declared.
        nodes: nodes seen.
        last_error: the latest MetricQ error (one line), or "".
        retry_in_s: seconds until the next attempt while ``down``.
    """

    broker: str = "connecting"
    daemon: str = "waiting"
    messages: int = 0
    points_in: int = 0
    points_sent: int = 0
    points_waiting: int = 0
    points_dropped: int = 0
    out_of_order: int = 0
    stream_gaps: int = 0
    daemon_restarts: int = 0
    broker_connects: int = 0
    broker_failures: int = 0
    metrics: int = 0
    nodes: int = 0
    last_error: str = ""
    retry_in_s: float = 0.0

    @property
    def reconnects(self) -> int:
        """Connections after the first."""
        return max(0, self.broker_connects - 1)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (with ``reconnects``)."""
        return {**asdict(self), "reconnects": self.reconnects}

    def line(self) -> str:
        """One log line."""
        text = (f"broker {self.broker}, daemon {self.daemon}: {self.messages} messages, "
                f"{self.points_sent} points sent, {self.points_waiting} waiting, "
                f"{self.points_dropped} dropped, {self.reconnects} reconnects")
        if self.broker == "down":
            text += f"; retry in {self.retry_in_s:.0f} s ({self.last_error})"
        return text

    def write(self, path: str | os.PathLike[str]) -> None:
        """Write :meth:`to_dict` as JSON to ``path`` atomically (a temporary file renamed)."""
        target = Path(path)
        temporary = target.with_name(target.name + ".tmp")
        temporary.write_text(json.dumps(self.to_dict(), indent=1) + "\n", encoding="utf-8")
        os.replace(temporary, target)
