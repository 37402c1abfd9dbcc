"""Work off the poll loop: one worker thread per kind of slow work, callbacks back in the loop.

A job runs on the worker's thread; its ``done(result)`` or ``failed(error)`` callback runs later *in
the loop* (:meth:`Worker.collect`), so callbacks may touch sockets. Jobs run in submission order.
The daemon has two workers: the model worker (kernel model, refit; :class:`Calibration` holds its
modeller and the latest ``calib`` body) and the store worker
(:class:`~hdeem_watch.daemon.store.worker.StoreWorker`).

Example:
    >>> jobs = Worker("example")
    >>> seen = []
    >>> jobs.submit(lambda: 6 * 7, seen.append)
    >>> jobs.shutdown(); seen
    [42]
"""

from __future__ import annotations

import concurrent.futures
import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from hdeem_watch.calibrate.group_fits import DEFAULT_MIN_SAMPLES
from hdeem_watch.calibrate.run_model import MAX_HISTORY, RunModeller, compact_fit
from hdeem_watch.wire.json_codec import dumps, quoted

if TYPE_CHECKING:
    from hdeem_watch.calibrate.group_rows import SensorGroup
    from hdeem_watch.dram.node import NodeTopology

log = logging.getLogger("hdeem_watch.daemon")

Job = tuple[concurrent.futures.Future[Any], Callable[[Any], None], Callable[[BaseException], None] | None]


class Worker:
    """One worker thread and the callbacks of its finished jobs.

    Args:
        name: the thread's name (``hdeem-<name>``).
        wake: called from the worker thread when a job finishes (e.g. to wake the poll loop).
    """

    def __init__(self, name: str = "model", wake: Callable[[], None] | None = None) -> None:
        self.worker = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"hdeem-{name}")
        self.name = name
        self.pending: list[Job] = []
        self._wake = wake

    def submit(self, job: Callable[[], Any], done: Callable[[Any], None],
               failed: Callable[[BaseException], None] | None = None) -> None:
        """Run ``job`` on the worker; :meth:`collect` later calls ``done(result)`` or ``failed(error)``."""
        future = self.worker.submit(job)
        self.pending.append((future, done, failed))
        if self._wake is not None:
            wake = self._wake
            future.add_done_callback(lambda _f: wake())

    @property
    def ready(self) -> bool:
        """Whether a finished job's callback waits for :meth:`collect`."""
        return any(future.done() for future, _done, _failed in self.pending)

    def collect(self, limit: int | None = None) -> None:
        """Call the callbacks of the finished jobs, at most ``limit`` of them (a failing callback is
        logged, not raised); the rest wait for the next call."""
        if not self.pending:
            return
        remaining = []
        budget = len(self.pending) if limit is None else limit
        for future, done, failed in self.pending:
            if budget <= 0 or not future.done():
                remaining.append((future, done, failed))
                continue
            budget -= 1
            if future.cancelled():  # shutting down
                continue
            try:
                error = future.exception()
                if error is None:
                    done(future.result())
                else:
                    log.error("%s job failed: %s: %s", self.name, type(error).__name__, quoted(str(error)))
                    if failed is not None:
                        failed(error)
            except Exception:
                log.exception("finishing a worker job failed")
        self.pending = remaining

    def shutdown(self, *, cancel_queued: bool = False) -> None:
        """Finish the running job (and the queued ones unless ``cancel_queued``); call the callbacks."""
        self.worker.shutdown(wait=True, cancel_futures=cancel_queued)
        self.collect()


#: The model worker (kept under its old name for callers).
ModelJobs = Worker


@dataclass
class Calibration:
    """The node's calibration: the run modeller (built and used on the model worker only) and the
    latest ``calib`` body (read and written in the loop).

    Attributes:
        body: the latest ``calib`` topic body (without the sim's truth).
        modeller: set on the model worker by its first job (None until then, or when it failed).
    """

    body: dict[str, Any] = field(default_factory=dict)
    modeller: RunModeller | None = None


@dataclass(frozen=True)
class ModelSettings:
    """What the run modeller is built from (see :class:`~hdeem_watch.calibrate.run_model.RunModeller`).

    ``topology`` is the node's :class:`~hdeem_watch.dram.node.NodeTopology`
    (:func:`hdeem_watch.node.topology.topology_from_node` of the configured/detected node); None =
    the legacy guess from ``dimms`` (the Taurus Haswell-EP blade for 8 DIMMs). ``groups``: the
    sensor groups fitted on their own (:func:`~hdeem_watch.calibrate.group_fits.source_groups`);
    ``dram_rates_hz``: each DRAM channel's sample rate, for the guard rail (runs with fewer than
    ``min_samples`` samples of a channel are recorded, not fitted).
    """

    memspec: str
    dimms: int = 8
    topology: NodeTopology | None = None
    currents: Sequence[str] = ("idd0", "idd2n", "idd3n", "idd4r", "idd4w")
    half_life_s: float | None = None
    physical_rules: bool = False
    max_requests: int | None = None
    groups: Sequence[SensorGroup] = ()
    dram_rates_hz: Mapping[str, float] | None = None
    min_samples: int = DEFAULT_MIN_SAMPLES


def restore_calibration(calibration: Calibration, *, settings: ModelSettings,
                        state: dict[str, Any] | None,
                        fits: Sequence[tuple[int, str | None, dict[str, Any] | None]],
                        submit: Callable[..., None], on_built: Callable[[], None],
                        on_unrestorable: Callable[[str, str | None], None] | None = None) -> None:
    """Restore the stored fit history and calibrator; build the run modeller as the worker's first job.

    Args:
        calibration: filled with the stored body now and the modeller on the worker.
        settings: the model's settings.
        state: the stored calibrator state (None = none).
        fits: the stored fit history, oldest first (a None fit is a ``calib.reset``).
        submit: the model worker's ``submit``.
        on_built: called in the loop once the modeller is built (or failed to build).
        on_unrestorable: called in the loop when the stored state could not be restored, with the
            reason and what was restored of it (JSON text: the node calibrator without the groups,
            or a fresh one; None without a modeller): the daemon moves the stored row to
            ``quarantine`` and stores that instead.
    """
    history: list[dict[str, Any]] = []
    for t_ns, _run_id, fit in fits[-MAX_HISTORY:]:
        if fit is None:
            history.clear()
        else:
            history.append(compact_fit(t_ns, fit))
    latest = fits[-1][2] if fits else None
    # Until the worker has built the model (importing the calibrator takes seconds), late joiners
    # get the stored fit.
    calibration.body = {"fit": latest, "history": history, "runs": len((state or {}).get("observations", [])),
                        "drift": {}, "memspec": settings.memspec, "model_error": None, "truth": None,
                        "loading": True}

    def build() -> tuple[dict[str, Any], str | None]:
        modeller = RunModeller(settings.memspec, dimms=settings.dimms, topology=settings.topology,
                               currents=settings.currents, half_life_s=settings.half_life_s or None,
                               physical_rules=settings.physical_rules,
                               max_requests=settings.max_requests, state=state, history=history,
                               groups=settings.groups, dram_rates_hz=settings.dram_rates_hz,
                               min_samples=settings.min_samples)
        restored = None
        if modeller.restore_error:
            log.warning("calibrator state not restored: %s", quoted(modeller.restore_error))
            restored = None if modeller.state() is None else dumps(modeller.state()).decode()
        if modeller.error:
            log.warning("runs will not be modelled: %s", modeller.error)
        calibration.modeller = modeller  # set on the worker: every later model job runs after this one
        return modeller.body(), restored

    def built(result: tuple[dict[str, Any], str | None]) -> None:
        body, restored = result
        calibration.body = body
        modeller = calibration.modeller
        if modeller is not None and modeller.restore_error and on_unrestorable is not None:
            on_unrestorable(modeller.restore_error, restored)
        on_built()

    def not_built(error: BaseException) -> None:
        calibration.body = {**calibration.body, "loading": False,
                            "model_error": f"model failed to build: {type(error).__name__}: {error}"}
        on_built()

    submit(build, built, not_built)
