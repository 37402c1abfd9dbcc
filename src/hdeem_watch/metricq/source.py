"""The MetricQ source: the daemon's stream published to MetricQ, reconnecting for ever.

Two tasks share one :class:`~hdeem_watch.metricq.outbox.Outbox`:

* the **reader** takes every stream message (:class:`~hdeem_watch.metricq.stream.StreamReader`),
  translates it (:class:`~hdeem_watch.metricq.translate.StreamTranslator`) and appends the points;
  it never waits for MetricQ;
* the **publisher** connects a :class:`HdeemSource` (a :class:`metricq.Source`: ``source.register``
  at the manager, then the data exchange it names), declares the metrics (``source.declare_metrics``)
  and every ``flush_interval_s`` sends one data chunk per metric with what is waiting. When the
  broker goes away, ``aio-pika``'s robust connection reconnects; when that does not succeed within
  ``agent_timeout_s`` or the first connection fails, the publisher starts a new agent after a
  backoff that doubles from 1 s up to ``reconnect_max_s``. Points that could not be published go
  back in the outbox.

Only this module imports the optional ``metricq`` package (``pip install 'hdeem-watch[metricq]'``).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

import metricq
from hdeem_watch.metricq.naming import MetricNames
from hdeem_watch.metricq.outbox import Outbox
from hdeem_watch.metricq.settings import SourceSettings, redacted
from hdeem_watch.metricq.status import SourceStatus
from hdeem_watch.metricq.stream import StreamReader
from hdeem_watch.metricq.translate import Points, StreamTranslator

log = logging.getLogger("hdeem-watch.metricq")

#: How long one connection attempt (register at the manager, open the data connection) may take.
CONNECT_TIMEOUT_S = 20.0
#: How long waiting points may take to go out when the source is stopped.
STOP_FLUSH_S = 5.0
#: How long one publish round may wait for the broker before the agent is replaced.
PUBLISH_TIMEOUT_S = 30.0


class HdeemSource(metricq.Source):
    """A :class:`metricq.Source` whose data come from outside (the publisher task), not from ``task``.

    Args:
        on_connection: called with False when one of its AMQP connections is lost and True when
            ``aio-pika`` restored it (the status shows the broker ``down`` in between).
    """

    def __init__(self, *args: Any, on_connection: Callable[[bool], None] | None = None, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.on_connection = on_connection

    def _on_close(self, sender: Any, exception: BaseException | None) -> None:
        super()._on_close(sender, exception)
        if self.on_connection is not None and not isinstance(exception, asyncio.CancelledError):
            self.on_connection(False)

    def _on_reconnect(self, sender: Any) -> None:
        super()._on_reconnect(sender)
        if self.on_connection is not None:
            self.on_connection(True)

    async def task(self) -> None:
        """Wait until stopped (the publisher of :func:`run_source` sends the data)."""
        assert self.task_stop_future is not None
        await self.task_stop_future

    async def teardown(self) -> None:
        """Close the connections, also after a connect that failed half-way (no task yet)."""
        if self._task is None:
            await metricq.DataClient.teardown(self)
        else:
            await super().teardown()

    async def publish(self, batch: Sequence[Points], sent: set[str]) -> None:
        """Send one data chunk per metric of ``batch`` (the points of a metric merged, in order).

        Args:
            batch: the points to send.
            sent: filled with the metrics sent so far, so that a caller whose call failed or was
                cancelled can queue the rest again.

        Raises:
            metricq.PublishFailed, asyncio.TimeoutError ...: a send failed (the rest is unsent).
        """
        merged: dict[str, list[Points]] = {}
        for p in batch:
            merged.setdefault(p.metric, []).append(p)
        for name, parts in merged.items():
            t_ns = np.concatenate([p.t_ns for p in parts]) if len(parts) > 1 else parts[0].t_ns
            values = np.concatenate([p.values for p in parts]) if len(parts) > 1 else parts[0].values
            metric = self[name]
            chunk = metric.chunk
            # A DataChunk holds the first time and then differences; filled as whole arrays here
            # instead of one append per value (the rate is 1600 values/s/node).
            del chunk.time_delta[:]
            del chunk.value[:]
            chunk.time_delta.extend(np.diff(t_ns, prepend=np.int64(0)).tolist())
            chunk.value.extend(values.tolist())
            metric.previous_timestamp = int(t_ns[-1])
            try:
                await metric.flush()
            finally:
                if not metric.empty:  # not sent: forget it here, the caller queues it again
                    del chunk.time_delta[:]
                    del chunk.value[:]
                    metric.previous_timestamp = 0
            sent.add(name)


def backoff_delays(maximum_s: float) -> Callable[[], float]:
    """A function returning 1, 2, 4, ... seconds, at most ``maximum_s`` (bounded exponential backoff).

    Example:
        >>> nxt = backoff_delays(5)
        >>> [nxt() for _ in range(5)]
        [1.0, 2.0, 4.0, 5.0, 5.0]
    """
    state = {"next": 1.0}

    def next_delay() -> float:
        delay = min(state["next"], maximum_s)
        state["next"] = min(state["next"] * 2, maximum_s)
        return delay

    return next_delay


class SourceRunner:
    """The reader and publisher tasks of one source process.

    Args:
        settings: checked settings (:func:`~hdeem_watch.metricq.settings.load_source_settings`).
        endpoints: the daemons' stream endpoints.
        flush_interval_s: how often waiting points are sent (one chunk per metric each time).
        agent_timeout_s: how long a lost connection may take to come back before the agent is replaced.
        clock: monotonic seconds (injected for tests).
    """

    def __init__(self, settings: SourceSettings, endpoints: Sequence[str], *, flush_interval_s: float = 0.2,
                 agent_timeout_s: float = 60.0, clock: Callable[[], float] = time.monotonic) -> None:
        self.settings = settings
        self.endpoints = list(endpoints)
        self.flush_interval_s = flush_interval_s
        self.agent_timeout_s = agent_timeout_s
        self.clock = clock
        self.status = SourceStatus()
        self.translator = StreamTranslator(MetricNames(settings.prefix), settings.metrics)
        self.outbox = Outbox(settings.buffer_points)
        self._pending_declarations: dict[str, dict[str, Any]] = {}
        self._stop = asyncio.Event()
        self._nodes: set[str] = set()
        self._publishing = False  # a batch taken from the outbox is on its way

    def stop(self) -> None:
        """Ask the tasks to end: reading stops at once, waiting points get up to ``STOP_FLUSH_S`` to go."""
        self._stop.set()

    async def run(self) -> None:
        """Run until :meth:`stop`; returns after every task ended (the status file shows ``stopped``)."""
        reader = asyncio.create_task(self._read())
        publisher = asyncio.create_task(self._publish_forever())
        reporter = asyncio.create_task(self._report())
        await self._stop.wait()
        await _cancel(reader)
        deadline = time.monotonic() + STOP_FLUSH_S
        while ((len(self.outbox) or self._publishing) and self.status.broker == "connected"
               and time.monotonic() < deadline):
            await asyncio.sleep(0.05)
        await _cancel(publisher)
        await _cancel(reporter)
        self.status.broker = "stopped"
        self._refresh()
        self._write_status()

    def _refresh(self) -> None:
        s = self.status
        s.points_waiting = len(self.outbox)
        s.points_dropped = self.outbox.dropped
        s.out_of_order = self.translator.out_of_order
        s.metrics = len(self.translator.declared)
        s.nodes = len(self._nodes)

    async def _report(self) -> None:
        while True:
            self._refresh()
            log.info("%s", self.status.line())
            self._write_status()
            await asyncio.sleep(self.settings.status_interval_s)

    def _write_status(self) -> None:
        if self.settings.status_file:
            try:
                self.status.write(self.settings.status_file)
            except OSError as error:
                log.warning("cannot write the status file %s: %s", self.settings.status_file, error)

    async def _read(self) -> None:
        reader = StreamReader(self.endpoints, **curve_options(self.settings))
        try:
            last = self.clock()
            while True:
                messages = await reader.receive(timeout_s=0.5)
                self.status.stream_gaps = reader.gaps.missed
                self.status.daemon_restarts = reader.gaps.restarts
                if not messages:
                    if self.status.daemon == "streaming" and self.clock() - last > self.settings.daemon_silence_s:
                        self.status.daemon = "silent"
                        log.warning("no message from the daemon for %.0f s", self.settings.daemon_silence_s)
                    continue
                last = self.clock()
                if self.status.daemon != "streaming":
                    log.info("daemon stream: streaming")
                self.status.daemon = "streaming"
                for message in messages:
                    self.status.messages += 1
                    self._nodes.add(message.node)
                    translation = self.translator.translate(message)
                    self._pending_declarations.update(translation.declarations)
                    self.status.points_in += sum(len(p) for p in translation.points)
                    self.outbox.push(translation.points)
        finally:
            reader.close()

    async def _publish_forever(self) -> None:
        next_delay = backoff_delays(self.settings.reconnect_max_s)
        while True:
            source = HdeemSource(self.settings.token, self.settings.server, on_connection=self._connection_changed,
                                 connection_timeout=self.agent_timeout_s, client_version=_version())
            try:
                await asyncio.wait_for(source.connect(), CONNECT_TIMEOUT_S)
                self.status.broker = "connected"
                self.status.broker_connects += 1
                log.info("connected to MetricQ at %s as %s", redacted(self.settings.server), self.settings.token)
                next_delay = backoff_delays(self.settings.reconnect_max_s)
                self._pending_declarations = dict(self.translator.declared)
                await self._publish_while_alive(source)
            except asyncio.CancelledError:
                await _stop_quietly(source)
                raise
            except Exception as error:  # every MetricQ/AMQP failure: retry with a new agent
                self.status.broker_failures += 1
                self.status.last_error = _one_line(error)
            await _stop_quietly(source)
            delay = next_delay()
            self.status.broker = "down"
            self.status.retry_in_s = delay
            log.warning("MetricQ unreachable (%s); retrying in %.0f s", self.status.last_error, delay)
            await asyncio.sleep(delay)

    def _connection_changed(self, up: bool) -> None:
        if up:
            self.status.broker = "connected"
            self.status.broker_connects += 1
            log.info("connection to MetricQ restored")
        elif self.status.broker == "connected":
            self.status.broker = "down"
            self.status.broker_failures += 1
            self.status.last_error = "connection lost; aio-pika reconnects every 5 s"
            log.warning("connection to MetricQ lost; reconnecting")

    async def _publish_while_alive(self, source: HdeemSource) -> None:
        stopped = asyncio.ensure_future(source.stopped())
        try:
            while not stopped.done():
                await asyncio.sleep(self.flush_interval_s)
                if self._pending_declarations:
                    declarations = self._pending_declarations
                    self._pending_declarations = {}
                    try:
                        # metricq adds chunkSize to the metadata dicts it is given: hand it copies.
                        copies = {name: dict(meta) for name, meta in declarations.items()}
                        await asyncio.wait_for(source.declare_metrics(copies), PUBLISH_TIMEOUT_S)
                    except BaseException:
                        self._pending_declarations = {**declarations, **self._pending_declarations}
                        raise
                batch = self.outbox.take()
                if not batch:
                    continue
                sent: set[str] = set()
                self._publishing = True
                try:
                    await asyncio.wait_for(source.publish(batch, sent), PUBLISH_TIMEOUT_S)
                except BaseException:
                    self.outbox.requeue([p for p in batch if p.metric not in sent])
                    raise
                finally:
                    self._publishing = False
                self.status.points_sent += sum(len(p) for p in batch)
            stopped.result()
            raise RuntimeError("the MetricQ agent stopped")
        finally:
            stopped.cancel()


def curve_options(settings: SourceSettings) -> dict[str, Any]:
    """The :class:`StreamReader` CURVE arguments of ``settings`` (none for plain streams).

    Raises:
        InputError: an unreadable certificate, or a client certificate without its secret key.
    """
    if not settings.curve_server_key_file:
        return {}
    from hdeem_watch.wire.keys import load_public_key, load_secret_key

    client = load_secret_key(settings.curve_client_key_file) if settings.curve_client_key_file else None
    return {"curve_server_key": load_public_key(settings.curve_server_key_file), "curve_client_keys": client}


async def _cancel(task: asyncio.Task[None]) -> None:
    task.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await task


async def _stop_quietly(source: HdeemSource) -> None:
    with contextlib.suppress(BaseException):
        await asyncio.wait_for(source.stop(silent=True), 10.0)


def _one_line(error: BaseException | None) -> str:
    if error is None:
        return "unknown error"
    text = str(error).splitlines()[0] if str(error) else ""
    cause = error.__cause__
    if cause is not None and str(cause):
        text = f"{text}: {str(cause).splitlines()[0]}" if text else str(cause).splitlines()[0]
    return f"{type(error).__name__}: {text}" if text else type(error).__name__


def _version() -> str:
    from hdeem_watch import __version__

    return f"hdeem-watch/{__version__}"
