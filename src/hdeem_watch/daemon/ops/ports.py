"""The narrow interfaces the daemon's parts get instead of the daemon object.

:class:`PublisherPort` is what the ops use of the publisher for everything but samples; :data:`Submit`
runs a job off the poll loop and calls back in it; :data:`Reply` completes a deferred control reply.
Tests drive the operations through fakes of these (and of
:class:`~hdeem_watch.daemon.store.port.StorePort`, the store as they use it).
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


class PublisherPort(Protocol):
    """The publisher's topics other than samples (``status``, ``run``, ``calib``, ``baseline``)."""

    def publish(self, kind: str, body: Mapping[str, Any], /) -> object: ...
