"""Announce benchmark runs to the node daemon (``run.start`` / ``run.stop`` on its control socket).

The daemon integrates the DRAM energy over each announced window and refits its calibration when
the run stops. An :class:`Announcer` gives the runner's ``on_start``/``on_stop`` hooks; a failing
daemon in the middle of a sweep turns announcing off (with a warning) instead of losing the sweep.

Example:
    >>> announcer = Announcer("ipc:///tmp/no-such-daemon/control.sock", timeout_s=0.1)
    >>> try:
    ...     announcer.check()
    ... except Exception as error:
    ...     print(type(error).__name__)
    InputError
"""

from __future__ import annotations

import os
import socket
from collections.abc import Callable, Mapping
from typing import Any

from hdeem_watch.bench.schedule import RunSpec
from hdeem_watch.daemon.client import ControlClient, ControlError, DaemonUnreachable
from hdeem_watch.errors import InputError


def run_name(spec: RunSpec) -> str:
    """Return the name a run is announced under, e.g. ``"triad-24t"``."""
    return f"{spec.kernel}-{spec.threads}t"


class Announcer:
    """Announces runs to one daemon.

    Args:
        endpoint: the daemon's control endpoint (``ipc://...`` or ``tcp://...``).
        timeout_s: reply timeout per request.
        metadata: extra fields sent with every ``run.start`` (e.g. the SLURM job id).
        warn: called with a one-line message when announcing fails mid-sweep.
        client: an already built client (tests); default ``ControlClient(endpoint, timeout_s)``.
    """

    def __init__(self, endpoint: str, *, timeout_s: float = 5.0, metadata: Mapping[str, Any] | None = None,
                 warn: Callable[[str], None] | None = None, client: Any = None) -> None:
        self.endpoint = endpoint
        self.client = client if client is not None else ControlClient(endpoint, timeout_s=timeout_s)
        self.metadata = dict(metadata or {})
        self.warn = warn or (lambda message: None)
        self.enabled = True
        self._run_id: Any = None

    def check(self) -> Mapping[str, Any]:
        """Ask the daemon for its status; raise :class:`InputError` if it does not answer."""
        try:
            result = self.client.call("status")
        except (DaemonUnreachable, ControlError) as error:
            raise InputError(f"--daemon {self.endpoint}: no daemon answers there ({error}); "
                             "expected the control endpoint of a running 'hdeem-watch daemon'") from None
        return result if isinstance(result, Mapping) else {}

    def start_args(self, spec: RunSpec) -> dict[str, Any]:
        """Return the ``run.start`` arguments for ``spec``."""
        return {"name": run_name(spec), "kernel": spec.kernel, "threads": spec.threads,
                "elements": spec.elements, "repeat": spec.repeat,
                "metadata": {"host": socket.gethostname(), "pid": os.getpid(), "tool": "hdeem-watch bench",
                             **self.metadata}}

    def on_start(self, spec: RunSpec) -> dict[str, Any]:
        """Runner hook: announce the start; return ``{"run_id": ...}`` (empty if disabled)."""
        self._run_id = None
        if not self.enabled:
            return {}
        try:
            result = self.client.call("run.start", self.start_args(spec))
        except (DaemonUnreachable, ControlError) as error:
            self._disable(f"run.start failed for {run_name(spec)}: {error}")
            return {}
        self._run_id = result.get("run_id") if isinstance(result, Mapping) else result
        return {"run_id": self._run_id}

    def on_stop(self, spec: RunSpec) -> dict[str, Any]:
        """Runner hook: announce the stop; return ``{"daemon": <run.stop result>}``."""
        if not self.enabled or self._run_id is None:
            return {}
        try:
            result = self.client.call("run.stop", {"run_id": self._run_id})
        except (DaemonUnreachable, ControlError) as error:
            self._disable(f"run.stop failed for {run_name(spec)} (run {self._run_id}): {error}")
            return {}
        finally:
            self._run_id = None
        return {"daemon": result}

    def _disable(self, message: str) -> None:
        self.enabled = False
        self.warn(f"{message}; further runs are not announced")

    def close(self) -> None:
        """Close the control connection."""
        close = getattr(self.client, "close", None)
        if close is not None:
            close()
