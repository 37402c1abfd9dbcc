"""Announce benchmark runs to the node daemon (``run.start`` / ``run.stop`` on its control socket).

The daemon integrates the DRAM energy over each announced window and refits its calibration when
the run stops. ``run.start`` carries the CPUs the workers were pinned to and the arrays' size
(``metadata.cpus``, ``metadata.array_bytes``), so the daemon models the run on the sockets it ran on. An :class:`Announcer` gives the runner's ``on_start``/``on_stop`` hooks; a failing
daemon in the middle of a sweep turns announcing off (with a warning) instead of losing the sweep.
A daemon that refuses ``run.start`` because another run is open (``conflict``: another bench, the
TUI's baseline, a SLURM job's announcement) is asked again every ``retry_s`` for up to ``wait_s``
(default 60 s); if it still refuses, :class:`RunRefused` ends the sweep, so that a batch script sees
a non-zero exit instead of runs without energies.

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
import time
from collections.abc import Callable, Mapping
from typing import Any

import zmq

from hdeem_watch.bench.schedule import HOLDOUT_KERNELS, RunSpec
from hdeem_watch.errors import InputError
from hdeem_watch.wire.client import ControlClient, ControlError, DaemonUnreachable, HandshakeFailed


def run_name(spec: RunSpec) -> str:
    """Return the name a run is announced under, e.g. ``"triad-24t"``."""
    return f"{spec.kernel}-{spec.threads}t"


#: How long ``run.start`` is retried while the daemon has another run open (s), and how often.
WAIT_S = 60.0
RETRY_S = 1.0


class RunRefused(RuntimeError):
    """The daemon still refused ``run.start`` (another run open) after the bounded wait."""


class Announcer:
    """Announces runs to one daemon.

    Args:
        endpoint: the daemon's control endpoint (``ipc://...`` or ``tcp://...``).
        timeout_s: reply timeout per request.
        metadata: extra fields sent with every ``run.start`` (e.g. the SLURM job id).
        warn: called with a one-line message when announcing fails mid-sweep or has to wait.
        client: an already built client (tests); default ``ControlClient(endpoint, timeout_s)``.
        wait_s: how long a ``run.start`` refused with ``conflict`` is retried before
            :class:`RunRefused` is raised.
        retry_s: the pause between those retries.
        clock: monotonic clock in seconds (injected by tests).
        sleep: how to pause (injected by tests).
    """

    def __init__(self, endpoint: str, *, timeout_s: float = 5.0, metadata: Mapping[str, Any] | None = None,
                 warn: Callable[[str], None] | None = None, client: Any = None, wait_s: float = WAIT_S,
                 retry_s: float = RETRY_S, clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        self.endpoint = endpoint
        self.client = client if client is not None else ControlClient(endpoint, timeout_s=timeout_s)
        self.metadata = dict(metadata or {})
        self.warn = warn or (lambda message: None)
        self.enabled = True
        self.wait_s = float(wait_s)
        self.retry_s = float(retry_s)
        self._clock = clock
        self._sleep = sleep
        self._run_id: Any = None

    def check(self) -> Mapping[str, Any]:
        """Ask the daemon for its status.

        Raises:
            InputError: the endpoint is not a ZeroMQ endpoint, or no daemon answers there.
        """
        try:
            result = self.client.call("status")
        except zmq.ZMQError as error:
            raise InputError(f"--daemon {self.endpoint!r}: not a usable ZeroMQ endpoint ({error}); expected "
                             "e.g. ipc:///run/hdeem-watch/control.sock or tcp://node7:5591") from None
        except HandshakeFailed as error:  # a daemon answers, but refuses this client's keys: say only why
            raise InputError(f"--daemon {self.endpoint}: {error}") from None
        except (DaemonUnreachable, ControlError) as error:
            raise InputError(f"--daemon {self.endpoint}: no daemon answers there ({error}); "
                             "expected the control endpoint of a running 'hdeem-watch daemon'") from None
        return result if isinstance(result, Mapping) else {}

    def start_args(self, spec: RunSpec) -> dict[str, Any]:
        """Return the ``run.start`` arguments for ``spec``.

        A placed spec (:class:`~hdeem_watch.bench.runner.PlacedRunSpec`, what the runner passes)
        adds ``metadata.cpus`` (the CPU of each worker) and ``metadata.array_bytes``: in the
        metadata, which every daemon version stores, so older daemons keep accepting the call
        and newer ones model the run on the sockets it ran on.
        """
        placement: dict[str, Any] = {}
        cpus = getattr(spec, "cpus", ())
        if cpus:
            placement["cpus"] = [int(c) for c in cpus]
        array_bytes = getattr(spec, "array_bytes", 0)
        if array_bytes:
            placement["array_bytes"] = int(array_bytes)
        if spec.kernel in HOLDOUT_KERNELS:  # predicted with the fit from before it, never fitted
            placement["holdout"] = True
        return {"name": run_name(spec), "kernel": spec.kernel, "threads": spec.threads,
                "elements": spec.elements, "repeat": spec.repeat,
                "metadata": {"host": socket.gethostname(), "pid": os.getpid(), "tool": "hdeem-watch bench",
                             **placement, **self.metadata}}

    def on_start(self, spec: RunSpec) -> dict[str, Any]:
        """Runner hook: announce the start; return ``{"run_id": ...}`` (empty if disabled)."""
        self._run_id = None
        if not self.enabled:
            return {}
        try:
            result = self._start(spec)
        except (DaemonUnreachable, ControlError) as error:
            self._disable(f"run.start failed for {run_name(spec)}: {error}")
            return {}
        self._run_id = result.get("run_id") if isinstance(result, Mapping) else result
        return {"run_id": self._run_id}

    def _start(self, spec: RunSpec) -> Any:
        """``run.start``, asked again while the daemon answers ``conflict``, for up to ``wait_s``.

        Raises:
            RunRefused: still ``conflict`` after ``wait_s``.
        """
        deadline = self._clock() + self.wait_s
        while True:
            try:
                return self.client.call("run.start", self.start_args(spec))
            except ControlError as error:
                if error.code != "conflict":
                    raise
                left = deadline - self._clock()
                if left <= 0:
                    raise RunRefused(f"the daemon at {self.endpoint} still refused run.start for "
                                     f"{run_name(spec)} after waiting {self.wait_s:g} s: {error.message}") from None
                self.warn(f"the daemon has another run open ({error.message}); waiting up to "
                          f"{self.wait_s:g} s for it to end")
                self._sleep(min(self.retry_s, left))

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

    def abort_open(self) -> str | None:
        """Abort the run this announcer opened and has not stopped (``run.stop`` with ``abort``:
        stored, not calibrated), e.g. on Ctrl-C, so the daemon takes the next run at once.

        A run whose ``run.start`` reply never arrived (interrupted while waiting for it) is found
        in the daemon's status by this process's id. Returns the aborted run's id, or None when
        none was open (or the daemon did not answer).
        """
        run_id = self._run_id
        try:
            if run_id is None:
                status = self.client.call("status")
                run = status.get("run") if isinstance(status, Mapping) else None
                metadata = run.get("metadata") if isinstance(run, Mapping) else None
                if not isinstance(run, Mapping) or not isinstance(metadata, Mapping) \
                        or metadata.get("pid") != os.getpid() or metadata.get("host") != socket.gethostname():
                    return None
                run_id = run.get("run_id")
            self.client.call("run.stop", {"run_id": run_id, "abort": True})
        except (DaemonUnreachable, ControlError):
            return None
        finally:
            self._run_id = None
        return str(run_id)

    def _disable(self, message: str) -> None:
        self.enabled = False
        self.warn(f"{message}; further runs are not announced")

    def close(self) -> None:
        """Close the control connection."""
        close = getattr(self.client, "close", None)
        if close is not None:
            close()
