"""The control operations of the daemon, and the life of run and idle-baseline windows.

Ops (see ``docs/protocol.md``): ``ping``, ``status``, ``run.start``, ``run.stop``, ``runs.list``,
``baseline.get``, ``baseline.measure``, ``calib.get``, ``calib.reset``.

A run: ``run.start`` polls the source once (so the window starts at a poll boundary), opens a
:class:`~hdeem_watch.daemon.windows.Window`, stores the record and tells the source
(``on_run``, the sim reacts to it). ``run.stop`` polls again, tells the source, and asks the window
to close at the first poll whose DRAM samples reach the stop; the reply is deferred until the
window closed and the worker modelled the run and refitted the calibrator. An idle run (kernel
``idle``) is also an idle baseline of every channel.

Example:
    >>> sorted(Operations.OPS)[:3]
    ['baseline.get', 'baseline.measure', 'calib.get']
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING, Any, Literal

from hdeem_watch import __version__
from hdeem_watch.daemon import baselines as bl
from hdeem_watch.daemon import protocol
from hdeem_watch.daemon.control import Handler, OpError, Pending
from hdeem_watch.daemon.runs import finish_record, new_record, parse_run_args
from hdeem_watch.daemon.windows import Window
from hdeem_watch.errors import InputError

if TYPE_CHECKING:
    from hdeem_watch.daemon.service import Daemon

log = logging.getLogger("hdeem_watch.daemon")

#: How long a closing window waits for lagging samples (monotonic seconds) before it closes anyway.
CLOSE_GRACE_S = 3.0
#: Longest ``baseline.measure`` window in seconds.
MAX_BASELINE_S = 3600.0


class Operations:
    """Control handlers bound to one :class:`~hdeem_watch.daemon.service.Daemon`."""

    OPS = ("ping", "status", "run.start", "run.stop", "runs.list", "baseline.get", "baseline.measure",
           "calib.get", "calib.reset")

    def __init__(self, daemon: Daemon) -> None:
        self.d = daemon

    def handlers(self) -> dict[str, Handler]:
        """op name → handler."""
        return {op: getattr(self, "op_" + op.replace(".", "_")) for op in self.OPS}

    # -- simple queries --------------------------------------------------------------------------------

    def op_ping(self, args: dict[str, Any]) -> dict[str, Any]:
        """Liveness."""
        return {"pong": True, "t_ns": time.time_ns()}

    def op_status(self, args: dict[str, Any]) -> dict[str, Any]:
        """The heartbeat body plus node, version and counts."""
        body = self.d.reporter.status_body()
        assert self.d.store is not None
        body.update({"node": self.d.node, "version": __version__, "runs": self.d.store.count_runs(),
                     "model_error": self.d.calib_body.get("model_error")})
        return body

    def op_runs_list(self, args: dict[str, Any]) -> dict[str, Any]:
        """Stored runs, newest first."""
        limit = args.get("limit", 100)
        if isinstance(limit, bool) or not isinstance(limit, int) or not 1 <= limit <= 100_000:
            raise OpError("bad-args", f"args.limit = {limit!r}: expected an integer 1..100000")
        kernel = args.get("kernel")
        if kernel is not None and not isinstance(kernel, str):
            raise OpError("bad-args", f"args.kernel = {kernel!r}: expected a string")
        assert self.d.store is not None
        return {"runs": self.d.store.list_runs(limit, kernel)}

    def op_baseline_get(self, args: dict[str, Any]) -> dict[str, Any]:
        """The current baselines."""
        return bl.baselines_body(self.d.baselines)

    def op_calib_get(self, args: dict[str, Any]) -> dict[str, Any]:
        """The latest calibration (with the sim's truth when simulated)."""
        return self.d.reporter.calib_with_truth()

    def op_calib_reset(self, args: dict[str, Any]) -> Pending:
        """Forget every calibration run (on the worker, after any refit in progress)."""
        pending = Pending("calib.reset")

        def job() -> dict[str, Any]:
            modeller = self.d.modeller  # read on the worker, after the job that built it
            if modeller is None:
                raise RuntimeError("the calibrator is not available (it failed to build; see the log)")
            modeller.reset()
            return modeller.body()

        def done(body: dict[str, Any]) -> None:
            assert self.d.store is not None
            self.d.store.clear_calibrator(time.time_ns())
            self.d.calib_body = body
            self.d.reporter.publish_calib()
            self.d.complete(pending, self.d.reporter.calib_with_truth())

        self.d.submit(job, done, failed=lambda error: self.d.complete(pending, error=("unavailable", str(error))))
        return pending

    # -- runs ------------------------------------------------------------------------------------------

    def _busy(self) -> None:
        for window in self.d.windows:
            if window.kind == "run":
                raise OpError("conflict", f"run {window.context['record']['run_id']} is in progress; stop it first")
            raise OpError("conflict", "an idle baseline measurement is in progress")

    def _notify_source(self, kind: Literal["start", "stop"], record: dict[str, Any], t_mono_ns: int) -> None:
        on_run = getattr(self.d.source, "on_run", None)
        if on_run is None:
            return
        from hdeem_watch.sources.base import RunEvent

        try:
            on_run(RunEvent(kind=kind, run_id=record["run_id"], kernel=record["kernel"], threads=record["threads"],
                            elements=record["elements"], repeat=record["repeat"], t_mono_ns=t_mono_ns))
        except Exception as error:
            log.warning("source on_run(%s) failed: %s", kind, error)

    def op_run_start(self, args: dict[str, Any]) -> dict[str, Any]:
        """Open a run window."""
        self._busy()
        run_args = parse_run_args(args)
        if not run_args.idle:
            try:
                from hdeem_watch.dram.kernels import canonical_kernel

                run_args = type(run_args)(**{**run_args.__dict__, "kernel": canonical_kernel(run_args.kernel)})
            except ImportError:
                pass
            except InputError as error:
                raise OpError("bad-args", f"args.kernel: {error} (or 'idle')") from None
        d = self.d
        assert d.store is not None and d.publisher is not None
        run_id = d.store.next_run_id()
        d.poll_once()
        now = d.clock()
        record = new_record(run_id, run_args, t_wall_ns=time.time_ns(), node=d.node)
        d.store.save_run(record)
        d.windows.append(Window(kind="run", start_energy_j=d.energies(), start_t_ns=d.last_sample_times(),
                                dram_channels=d.dram_channels, t_start_mono_ns=now,
                                context={"record": record, "waiters": []}))
        self._notify_source("start", record, now)
        for account in d.accounts.values():
            if account.history is not None:
                account.history.clear()
        d.publisher.publish("run", {"event": "start", "run": record})
        return {"run_id": run_id, "t_start_ns": record["t_start_ns"], "run": record}

    def _close_deadline(self, now: int, extra_s: float = 0.0) -> int:
        # Long enough for a lagging source to catch up (the sim holds its sensors back while it
        # plans a run, up to seconds on a loaded machine); a stalled channel ends the wait.
        slowest = max((1.0 / a.rate_hz for a in self.d.accounts.values() if a.rate_hz > 0), default=0.0)
        grace_s = max(CLOSE_GRACE_S, 4 * self.d.settings.poll_interval_s, 3 * slowest / self.d.speed)
        return now + round((extra_s + grace_s) * 1e9)

    def op_run_stop(self, args: dict[str, Any]) -> Any:
        """Close a run window; the reply (energies, model, fit) comes when it is modelled."""
        run_id = args.get("run_id")
        if not isinstance(run_id, str | int) or isinstance(run_id, bool):
            raise OpError("bad-args", f"args.run_id = {run_id!r}: expected the run id run.start returned")
        run_id = str(run_id)
        abort = args.get("abort", False)
        if not isinstance(abort, bool):
            raise OpError("bad-args", f"args.abort = {abort!r}: expected true or false")
        d = self.d
        window = next((w for w in d.windows if w.kind == "run" and w.context["record"]["run_id"] == run_id), None)
        if window is None:
            assert d.store is not None
            stored = d.store.get_run(run_id)
            if stored is not None and stored.get("state") != "running":
                return stored  # stopped before: the same answer again
            raise OpError("not-found", f"no run {run_id!r} in progress")
        pending = Pending("run.stop")
        window.context["waiters"].append(pending)
        if window.closing:
            return pending
        window.context["abort"] = abort
        d.poll_once()
        now = d.clock()
        self._notify_source("stop", window.context["record"], now)
        # The stop on the source's sample-time axis; the window closes once every DRAM channel has
        # delivered its samples up to it (a sensor may lag: the sim while it plans a run).
        window.request_close(target_t_ns=d.sample_time_of(now), deadline_mono_ns=self._close_deadline(now),
                             rates_hz=d.rates(), last_t_ns=d.last_sample_times(), energy_j=d.energies())
        self.advance_windows(now)
        return pending

    # -- idle baselines --------------------------------------------------------------------------------

    def op_baseline_measure(self, args: dict[str, Any]) -> Pending:
        """Measure an idle window of ``seconds``; the reply comes at its end."""
        seconds = args.get("seconds")
        if isinstance(seconds, bool) or not isinstance(seconds, int | float) or not 0 < seconds <= MAX_BASELINE_S:
            raise OpError("bad-args", f"args.seconds = {seconds!r}: expected a duration in (0, {MAX_BASELINE_S:g}] s")
        self._busy()
        d = self.d
        d.poll_once()
        now = d.clock()
        window = Window(kind="baseline", start_energy_j=d.energies(), start_t_ns=d.last_sample_times(),
                        dram_channels=d.dram_channels, t_start_mono_ns=now, context={"waiters": []})
        last = [t for c in d.dram_channels if (t := d.accounts[c].last_t_ns) is not None]
        start = max(last) if last else d.sample_time_of(now)
        window.request_close(target_t_ns=start + round(seconds * 1e9),
                             deadline_mono_ns=self._close_deadline(now, seconds / d.speed), rates_hz=d.rates())
        pending = Pending("baseline.measure")
        window.context["waiters"].append(pending)
        d.windows.append(window)
        return pending

    # -- closing windows -------------------------------------------------------------------------------

    def advance_windows(self, now_mono_ns: int) -> None:
        """Close every window that is ready (called after each poll)."""
        if not self.d.windows:
            return
        for window in [w for w in self.d.windows if w.ready(now_mono_ns)]:
            self.d.windows.remove(window)
            try:
                self._closed(window, now_mono_ns)
            except Exception as error:
                log.exception("closing a %s window failed", window.kind)
                for pending in window.context.get("waiters", []):
                    self.d.complete(pending, error=("internal", f"{type(error).__name__}: {error}"))

    def _window_baselines(self, window: Window, energy: dict[str, float], spans: dict[str, float]) -> dict[str, bl.Baseline]:
        found = {}
        for name, account in self.d.accounts.items():
            found[name] = bl.baseline_from_samples(window.channel_samples(name), t_ns=account.last_t_ns or 0,
                                                   origin="idle-run", energy_j=energy.get(name),
                                                   window_s=spans.get(name))
        changed = [self.d.reporter.update_baseline(name, b) for name, b in found.items()]
        if any(changed):
            self.d.reporter.publish_baselines()
        return found

    def _closed(self, window: Window, now: int) -> None:
        d = self.d
        energy, window_s, spans = window.result(d.energies(), d.last_sample_times(), now_mono_ns=now, speed=d.speed)
        waiters: list[Pending] = window.context.get("waiters", [])
        if window.kind == "baseline":
            found = self._window_baselines(window, energy, spans)
            body = bl.baselines_body(found)
            body["window_s"] = window_s
            for pending in waiters:
                d.complete(pending, body)
            return
        aborted = bool(window.context.get("abort"))
        record = finish_record(window.context["record"], energy_j=energy, window_s=window_s,
                               dram_channels=d.dram_channels, t_wall_ns=time.time_ns(), spans_s=spans,
                               aborted=aborted)
        # The window on each channel's sample axis: samples with first < t <= last are inside.
        record["samples_ns"] = {c: list(span) for c, span in window.sample_spans_ns.items()}
        assert d.store is not None
        d.store.save_run(record)
        if record["kernel"] in ("idle", "sleep") and not aborted:
            self._window_baselines(window, energy, spans)
        if aborted:
            self._finish_run(record, waiters, None)
            return
        def job() -> tuple[Any, ...]:
            modeller = d.modeller  # read on the worker, after the job that built it
            if modeller is None:
                raise RuntimeError("the model is not available (it failed to build; see the log)")
            try:
                model, fit, error = modeller.evaluate(record)
            except Exception as exc:  # a model bug must not lose the run or its reply
                log.exception("modelling run %s failed", record["run_id"])
                model, fit, error = None, None, f"model failed: {type(exc).__name__}: {exc}"
            # The calibrator's state grows with the runs (MBs after hundreds): serialise it here,
            # not in the poll loop.
            state = protocol.dumps(modeller.state()).decode() if fit is not None else None
            return model, fit, error, modeller.body(), state

        d.submit(job, lambda result: self._finish_run(record, waiters, result),
                 failed=lambda error: self._finish_run(record, waiters, (None, None, str(error), d.calib_body, None)))

    def _finish_run(self, record: dict[str, Any], waiters: list[Pending], result: tuple[Any, ...] | None) -> None:
        d = self.d
        assert d.store is not None and d.publisher is not None
        if result is not None:
            model, fit, error, body, state = result
            record["model"], record["fit"], record["model_error"] = model, fit, error
            d.store.save_run(record)
            if fit is not None and state is not None:
                d.store.save_calibration(int(record.get("t_stop_ns") or 0), state, fit, record["run_id"])
            d.calib_body = body
            if d.metrics is not None:
                d.metrics.observe_fit(fit)
        if d.metrics is not None:
            d.metrics.observe_run()
        d.publisher.publish("run", {"event": "stop", "run": record})
        if result is not None:
            d.reporter.publish_calib()
        for pending in waiters:
            d.complete(pending, record)

