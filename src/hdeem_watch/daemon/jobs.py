"""The daemon's model worker: slow jobs (the kernel model, the refit) run off the poll loop.

:func:`load_state` restores the daemon's stored baselines, fit history and calibrator at start and
builds the run modeller as the worker's first job.

A job runs on one worker thread; its ``done(result)`` or ``failed(error)`` callback runs later *in
the loop* (:meth:`ModelJobs.collect`), so callbacks may touch sockets and the database. Jobs run in
submission order.

Example:
    >>> jobs = ModelJobs()
    >>> seen = []
    >>> jobs.submit(lambda: 6 * 7, seen.append)
    >>> jobs.shutdown(); seen
    [42]
"""

from __future__ import annotations

import concurrent.futures
import logging
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from hdeem_watch.daemon import baselines as bl
from hdeem_watch.daemon.modelling import MAX_HISTORY, RunModeller, compact_fit

if TYPE_CHECKING:
    from hdeem_watch.daemon.service import Daemon

log = logging.getLogger("hdeem_watch.daemon")

Job = tuple[concurrent.futures.Future[Any], Callable[[Any], None], Callable[[BaseException], None] | None]


class ModelJobs:
    """One worker thread and the callbacks of its finished jobs."""

    def __init__(self) -> None:
        self.worker = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="hdeem-model")
        self.pending: list[Job] = []

    def submit(self, job: Callable[[], Any], done: Callable[[Any], None],
               failed: Callable[[BaseException], None] | None = None) -> None:
        """Run ``job`` on the worker; :meth:`collect` later calls ``done(result)`` or ``failed(error)``."""
        self.pending.append((self.worker.submit(job), done, failed))

    def collect(self) -> None:
        """Call the callbacks of the finished jobs (a failing callback is logged, not raised)."""
        if not self.pending:
            return
        remaining = []
        for future, done, failed in self.pending:
            if not future.done():
                remaining.append((future, done, failed))
                continue
            if future.cancelled():  # shutting down
                continue
            try:
                error = future.exception()
                if error is None:
                    done(future.result())
                else:
                    log.error("model job failed: %s: %s", type(error).__name__, error)
                    if failed is not None:
                        failed(error)
            except Exception:
                log.exception("finishing a model job failed")
        self.pending = remaining

    def shutdown(self) -> None:
        """Finish the running job (queued ones are cancelled) and call the finished jobs' callbacks."""
        self.worker.shutdown(wait=True, cancel_futures=True)
        self.collect()


def load_state(daemon: Daemon) -> None:
    """Restore stored baselines, fit history and calibrator; build the run modeller on the worker."""
    assert daemon.store is not None
    for channel, record in daemon.store.load_baselines().items():
        try:
            daemon.baselines[channel] = bl.Baseline.from_dict(record)
        except (ValueError, TypeError):
            log.warning("ignoring a malformed stored baseline of %s", channel)
    history: list[dict[str, Any]] = []
    for t_ns, _run_id, fit in daemon.store.fit_history(MAX_HISTORY):
        if fit is None:
            history.clear()  # a calib.reset
        else:
            history.append(compact_fit(t_ns, fit))
    state = daemon.store.load_calibrator()
    latest = next((fit for _t, _r, fit in reversed(daemon.store.fit_history(1))), None)
    # Until the worker has built the model (importing the calibrator takes seconds), late
    # joiners get the stored fit.
    daemon.calib_body = {"fit": latest, "history": history, "runs": len((state or {}).get("observations", [])),
                         "drift": {}, "memspec": daemon.settings.memspec, "model_error": None, "truth": None,
                         "loading": True}
    settings = daemon.settings

    def build() -> dict[str, Any]:
        modeller = RunModeller(
            settings.memspec, dimms=settings.dimms, currents=settings.currents,
            half_life_s=settings.half_life_s or None, max_requests=settings.model_max_requests,
            state=state, history=history,
        )
        if modeller.restore_error:
            log.warning("calibrator state not restored: %s", modeller.restore_error)
        if modeller.error:
            log.warning("runs will not be modelled: %s", modeller.error)
        daemon.modeller = modeller  # set on the worker: every later model job runs after this one
        return modeller.body()

    def built(body: dict[str, Any]) -> None:
        daemon.calib_body = body
        daemon.reporter.publish_calib()

    def not_built(error: BaseException) -> None:
        daemon.calib_body = {**daemon.calib_body, "loading": False,
                             "model_error": f"model failed to build: {type(error).__name__}: {error}"}

    daemon.submit(build, built, not_built)
