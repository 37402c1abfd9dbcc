"""The narrow interfaces the daemon's parts get instead of the daemon object.

:class:`StorePort` is what the daemon uses of :class:`~hdeem_watch.daemon.store.database.Store` (called only
from the store worker thread, :class:`~hdeem_watch.daemon.store.worker.StoreWorker`);
:class:`PublisherPort` what it uses of the publisher for everything but samples; :data:`Submit`
runs a job off the poll loop and calls back in it; :data:`Reply` completes a deferred control reply.
Tests drive the operations through fakes of these.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Protocol

from hdeem_watch.daemon.shell.control import Pending

Job = Callable[[], Any]
Done = Callable[[Any], None]
Failed = Callable[[BaseException], None]
#: ``submit(job, done, failed)``: run ``job`` on a worker; ``done(result)``/``failed(error)`` run in the loop.
Submit = Callable[[Job, Done, Failed | None], None]
#: ``reply(pending, result, error)``: send a deferred control reply (``error = (code, message)``).
Reply = Callable[[Pending, Any, "tuple[str, str] | None"], None]


class StorePort(Protocol):
    """The state database as the daemon uses it (see :class:`~hdeem_watch.daemon.store.database.Store`)."""

    def health(self) -> str: ...

    def next_run_id(self) -> str: ...

    def save_run(self, record: Mapping[str, Any]) -> bool: ...

    def get_run(self, run_id: str) -> dict[str, Any] | None: ...

    def list_runs(self, limit: int = 100, kernel: str | None = None, *, full: bool = False,
                  before: str | int | None = None) -> list[dict[str, Any]]: ...

    def count_runs(self) -> int: ...

    def close_interrupted_runs(self, t_ns: int) -> int: ...

    def save_calibration(self, t_ns: int, state: Mapping[str, Any] | str, fit: Mapping[str, Any] | None,
                         run_id: str | None) -> None: ...

    def load_calibrator(self) -> dict[str, Any] | None: ...

    def save_calibrator_state(self, t_ns: int, state: Mapping[str, Any] | str) -> None: ...

    def clear_calibrator(self, t_ns: int) -> None: ...

    def quarantine_calibrator(self, t_ns: int, reason: str) -> None: ...

    def save_alarm(self, t_ns: int, run_id: str | None, alarm: Mapping[str, Any]) -> None: ...

    def list_alarms(self, limit: int = 100) -> list[dict[str, Any]]: ...

    def fit_history(self, limit: int = 100) -> list[tuple[int, str | None, dict[str, Any] | None]]: ...

    def save_baseline(self, channel: str, record: Mapping[str, Any]) -> None: ...

    def load_baselines(self) -> dict[str, dict[str, Any]]: ...


class PublisherPort(Protocol):
    """The publisher's topics other than samples (``status``, ``run``, ``calib``, ``baseline``)."""

    def publish(self, kind: str, body: Mapping[str, Any], /) -> object: ...
