"""Messages between the UI's threads: small frozen dataclasses, all in this one module.

A control request from the UI (the ``b`` and ``s`` keys) runs in a short-lived thread of its own
(``baseline.measure`` replies only after its measurement). Its outcome does not touch the node's
model from that thread: the request thread puts one of these messages on its feed's queue, and
the feed thread — the model's only owner — turns it into the notice the key line shows.

Example:
    >>> RequestFailed("baseline.measure", "conflict", "run r3 is in progress; stop it first").notice
    'baseline.measure: conflict: run r3 is in progress; stop it first (s stops it)'
"""

from __future__ import annotations

from dataclasses import dataclass

#: Longest notice (the key line is one terminal row).
MAX_NOTICE = 120


@dataclass(frozen=True)
class RequestSent:
    """A request left the UI.

    Attributes:
        op: the control operation.
        seconds: the measurement length it asked for (None if the op has none).
    """

    op: str
    seconds: float | None = None

    @property
    def notice(self) -> str:
        """What the key line says."""
        return f"{self.op}: sent" + (f" ({self.seconds:g} s)" if self.seconds is not None else "")


@dataclass(frozen=True)
class RequestDone:
    """The daemon answered ``ok``.

    Attributes:
        op: the control operation.
        summary: a short summary of the result ("" if none).
    """

    op: str
    summary: str = ""

    @property
    def notice(self) -> str:
        """What the key line says."""
        return f"{self.op}: ok" + (f" ({self.summary})" if self.summary else "")


@dataclass(frozen=True)
class RequestFailed:
    """The daemon answered with an error.

    Attributes:
        op: the control operation.
        code: the protocol's error code (``conflict``, ``not-found``, ...).
        message: the daemon's message.
    """

    op: str
    code: str
    message: str

    @property
    def notice(self) -> str:
        """What the key line says (a conflict with a run in progress names the key that stops it)."""
        hint = " (s stops it)" if self.code == "conflict" and "stop it first" in self.message else ""
        return f"{self.op}: {self.code}: {self.message}"[: MAX_NOTICE - len(hint)] + hint


@dataclass(frozen=True)
class RequestUnanswered:
    """No reply in time (the daemon is gone or busy).

    Attributes:
        op: the control operation.
        timeout_s: how long the request waited.
    """

    op: str
    timeout_s: float

    @property
    def notice(self) -> str:
        """What the key line says."""
        return f"{self.op}: no reply within {self.timeout_s:g} s"


#: Every message a request thread sends to its feed.
RequestOutcome = RequestSent | RequestDone | RequestFailed | RequestUnanswered


@dataclass(frozen=True)
class ViewSettings:
    """What the app shows, read by the feeds; immutable: the app swaps in a new one whole.

    Attributes:
        window_s: the plot's time window.
        width: plot columns per channel.
        focus: index of the node whose plots are computed (others get table values only).
    """

    window_s: float = 60.0
    width: int = 120
    focus: int = 0
