"""Closed windows to their owner, by window kind.

The run book closes windows of three kinds (:data:`~hdeem_watch.daemon.book.windows.WindowKind`):
runs and baselines belong to :class:`~hdeem_watch.daemon.ops.node.Operations`, jobs to
:class:`~hdeem_watch.daemon.ops.jobs.JobOperations`. The poll loop and the ops that close a window
themselves (``job.stop``, ``baseline.cancel``) hand every closed window to one :class:`WindowRouter`;
its observers see each window first (the counter windows attach their counts to a run), then the
owner of its kind gets it. The composition root (:func:`hdeem_watch.daemon.compose.build_node`)
names the owners, once, before the first poll.

Example:
    >>> seen = []
    >>> router = WindowRouter(observers=[lambda w: seen.append(("observed", w))])
    >>> router.route("run", lambda w: seen.append(("run", w)))
    >>> router.route("job", lambda w: seen.append(("job", w)))
    >>> class Closed:
    ...     kind = "job"
    >>> router(Closed()); [what for what, _ in seen]
    ['observed', 'job']
    >>> router.missing()
    ['baseline']
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import get_args

from hdeem_watch.daemon.book.state import ClosedWindow
from hdeem_watch.daemon.book.windows import WindowKind

#: What gets a closed window: an observer or the owner of a kind.
WindowHandler = Callable[[ClosedWindow], None]


class WindowRouter:
    """Hands each closed window to its observers, then to the owner of its kind.

    Args:
        observers: called first with every closed window, in order.
    """

    def __init__(self, observers: Iterable[WindowHandler] = ()) -> None:
        self.observers = tuple(observers)
        self._owners: dict[str, WindowHandler] = {}

    def route(self, kind: WindowKind, owner: WindowHandler) -> None:
        """Give the closed windows of ``kind`` to ``owner`` (once per kind)."""
        if kind in self._owners:
            raise ValueError(f"closed {kind} windows already go to {self._owners[kind]!r}")
        self._owners[kind] = owner

    def missing(self) -> list[str]:
        """The window kinds that have no owner yet."""
        return [kind for kind in get_args(WindowKind) if kind not in self._owners]

    def __call__(self, closed: ClosedWindow) -> None:
        for observer in self.observers:
            observer(closed)
        owner = self._owners.get(closed.kind)
        if owner is None:
            raise LookupError(f"no owner for closed {closed.kind} windows (WindowRouter.route)")
        owner(closed)
