"""Optional Prometheus endpoint of the daemon, for sites that already scrape their nodes.

Metrics (Prometheus naming: base units, ``_total`` on counters):

* ``hdeem_watch_power_watts{node, channel}`` — latest power (gauge; NaN when unknown)
* ``hdeem_watch_energy_joules_total{node, channel}`` — the source's cumulative energy (counter)
* ``hdeem_watch_samples_total{node, channel}`` — samples received from the source
* ``hdeem_watch_missing_samples_total{node, channel}`` — samples known to be missing
* ``hdeem_watch_baseline_watts{node, channel}`` — the channel's idle baseline
* ``hdeem_watch_runs_total{node}`` — finished runs
* ``hdeem_watch_calibrated_current_amperes{node, current}`` — the latest calibrated currents
* ``hdeem_watch_calibration_error_ratio{node}`` — mean absolute relative error after the fit
* ``hdeem_watch_store_degraded{node}`` — 1 while state-database writes wait for the disk
* the standard ``process_cpu_seconds_total``, ``process_resident_memory_bytes``, ... of the daemon

Nothing is pushed: :class:`NodeCollector` reads the truth (the channel accounts, the baselines, the
latest fit) when Prometheus scrapes, the ``prometheus_client`` custom-collector pattern. Each daemon
uses its own :class:`prometheus_client.CollectorRegistry` (tests can run several).

Example:
    >>> m = DaemonMetrics(NodeCollector("n1", accounts=lambda: {}, baselines=lambda: {}, fit=lambda: None,
    ...                                 runs_finished=lambda: 3))
    >>> b"hdeem_watch_runs_total{node=\\"n1\\"} 3.0" in m.exposition()
    True
"""

from __future__ import annotations

import contextlib
import math
import socket
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, ProcessCollector, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric

from hdeem_watch.daemon.book.baselines import Baseline
from hdeem_watch.daemon.book.channels import ChannelAccount
from hdeem_watch.fit_record import FitRecord


class NodeCollector:
    """The node's metrics, evaluated at scrape time (on the HTTP server's thread).

    Args:
        node: the node label.
        accounts: the channel accounts now.
        baselines: the kept baselines now.
        fit: the latest ``FitResult.to_dict()`` (or None).
        runs_finished: finished runs since start.
        store_health: ``"ok"`` or ``"degraded: ..."``.
    """

    def __init__(self, node: str, *, accounts: Callable[[], Mapping[str, ChannelAccount]],
                 baselines: Callable[[], Mapping[str, Baseline]], fit: Callable[[], Mapping[str, Any] | None],
                 runs_finished: Callable[[], int], store_health: Callable[[], str] = lambda: "ok") -> None:
        self.node = node
        self._accounts = accounts
        self._baselines = baselines
        self._fit = fit
        self._runs = runs_finished
        self._store_health = store_health
        #: Last finite cumulative energy per channel: the counter holds it while the energy is unknown.
        self._energy_j: dict[str, float] = {}

    def collect(self) -> Iterator[Metric]:
        """Yield every metric family (called by the registry at each scrape)."""
        node = self.node
        power = GaugeMetricFamily("hdeem_watch_power_watts", "Latest power of the channel.", labels=["node", "channel"])
        energy = CounterMetricFamily("hdeem_watch_energy_joules", "Energy of the channel since the source opened.",
                                     labels=["node", "channel"])
        samples = CounterMetricFamily("hdeem_watch_samples", "Samples received from the source.",
                                      labels=["node", "channel"])
        missing = CounterMetricFamily("hdeem_watch_missing_samples", "Samples known to be missing (gaps).",
                                      labels=["node", "channel"])
        for name, account in list(self._accounts().items()):
            power.add_metric([node, name], account.power_w)
            if math.isfinite(account.energy_j) and account.energy_j >= self._energy_j.get(name, 0.0):
                self._energy_j[name] = account.energy_j
            energy.add_metric([node, name], self._energy_j.get(name, 0.0))
            samples.add_metric([node, name], account.samples)
            missing.add_metric([node, name], account.gaps)
        yield from (power, energy, samples, missing)
        baseline = GaugeMetricFamily("hdeem_watch_baseline_watts", "Idle baseline power of the channel.",
                                     labels=["node", "channel"])
        for name, kept in sorted(self._baselines().items()):
            baseline.add_metric([node, name], kept.power_w)
        yield baseline
        runs = CounterMetricFamily("hdeem_watch_runs", "Finished benchmark runs.", labels=["node"])
        runs.add_metric([node], self._runs())
        yield runs
        yield from _fit_metrics(node, self._fit())
        degraded = GaugeMetricFamily("hdeem_watch_store_degraded",
                                     "1 while state-database writes wait for the disk.", labels=["node"])
        degraded.add_metric([node], 0.0 if self._store_health() == "ok" else 1.0)
        yield degraded


def _fit_metrics(node: str, fit: Mapping[str, Any] | None) -> Iterator[Metric]:
    current = GaugeMetricFamily("hdeem_watch_calibrated_current_amperes", "Calibrated per-device DRAM current.",
                                labels=["node", "current"])
    error = GaugeMetricFamily("hdeem_watch_calibration_error_ratio",
                              "Mean absolute relative energy error after the fit.", labels=["node"])
    if fit:
        record = FitRecord.from_dict(fit)  # an unknown value is left out of the scrape, never 0
        for name, entry in sorted(record.currents.items()):
            if math.isfinite(entry.calibrated_a):
                current.add_metric([node, name], entry.calibrated_a)
        if math.isfinite(record.error.after):
            error.add_metric([node], record.error.after)
    yield current
    yield error


class DaemonMetrics:
    """The daemon's Prometheus registry and its HTTP endpoint.

    Args:
        collector: the node's collector.
        registry: registry to use (default: a fresh one).
    """

    def __init__(self, collector: NodeCollector, registry: CollectorRegistry | None = None) -> None:
        self.registry = registry or CollectorRegistry()
        # The standard process_* metrics (CPU seconds, resident memory, open files) of the daemon.
        ProcessCollector(registry=self.registry)
        self.registry.register(collector)
        self._server: Any = None

    def serve(self, port: int, addr: str = "127.0.0.1") -> int:
        """Start the HTTP endpoint in a background thread; return the bound port.

        The thread sleeps in ``select`` until a scrape arrives (the stock server wakes twice a
        second to look for a shutdown request); :meth:`close` wakes it with a connection.
        """
        server = _MetricsServer((addr, port), self.exposition)
        threading.Thread(target=server.serve_forever, kwargs={"poll_interval": None},
                         name="hdeem-metrics", daemon=True).start()
        self._server = server
        return int(server.server_address[1])

    def close(self) -> None:
        """Stop the HTTP endpoint if it runs."""
        server, self._server = self._server, None
        if server is None:
            return
        stopper = threading.Thread(target=server.shutdown, daemon=True)
        stopper.start()
        host, port = server.server_address[:2]
        loopback = {"0.0.0.0": "127.0.0.1", "::": "::1"}.get(host, host)
        deadline = time.monotonic() + 5.0
        while stopper.is_alive() and time.monotonic() < deadline:  # until the flag is seen
            with contextlib.suppress(OSError):
                socket.create_connection((loopback, port), timeout=0.5).close()
            stopper.join(0.05)
        server.server_close()

    def exposition(self) -> bytes:
        """The text exposition format of every metric (what a scrape returns)."""
        return generate_latest(self.registry)


class _MetricsServer(ThreadingHTTPServer):
    """A scrape endpoint: ``GET`` any path returns the exposition (IPv6 when ``addr`` is)."""

    daemon_threads = True

    def __init__(self, address: tuple[str, int], exposition: Callable[[], bytes]) -> None:
        self.address_family = socket.AF_INET6 if ":" in address[0] else socket.AF_INET
        self.exposition = exposition
        super().__init__(address, _ScrapeHandler)


class _ScrapeHandler(BaseHTTPRequestHandler):
    server: _MetricsServer

    def do_GET(self) -> None:
        body = self.server.exposition()
        self.send_response(200)
        self.send_header("Content-Type", CONTENT_TYPE_LATEST)
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, format: str, *args: Any) -> None:
        """Scrapes are not logged."""
