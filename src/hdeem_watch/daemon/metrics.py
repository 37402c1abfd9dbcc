"""Optional Prometheus endpoint of the daemon, for sites that already scrape their nodes.

Metrics (Prometheus naming: base units, ``_total`` on counters):

* ``hdeem_watch_power_watts{node, channel}`` — latest power (gauge; NaN when unknown)
* ``hdeem_watch_energy_joules_total{node, channel}`` — energy since the daemon started (counter)
* ``hdeem_watch_samples_total{node, channel}`` — samples received from the source
* ``hdeem_watch_missing_samples_total{node, channel}`` — samples known to be missing
* ``hdeem_watch_baseline_watts{node, channel}`` — the channel's idle baseline
* ``hdeem_watch_runs_total{node}`` — finished runs
* ``hdeem_watch_calibrated_current_amperes{node, current}`` — the latest calibrated currents
* ``hdeem_watch_calibration_error_ratio{node}`` — mean absolute relative error after the fit
* the standard ``process_cpu_seconds_total``, ``process_resident_memory_bytes``, ... of the daemon

Each daemon uses its own :class:`prometheus_client.CollectorRegistry` (tests can run several).

Example:
    >>> m = DaemonMetrics("n1")
    >>> m.observe_channel("DDR_AB", power_w=5.0, energy_delta_j=2.5, samples=10, missing=0)
    >>> b"hdeem_watch_energy_joules_total" in m.exposition()
    True
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from prometheus_client import (
    CollectorRegistry,
    Counter,
    Gauge,
    ProcessCollector,
    generate_latest,
    start_http_server,
)


class DaemonMetrics:
    """The daemon's Prometheus metrics (updated by the daemon, scraped over HTTP when served).

    Args:
        node: the node label.
        registry: registry to use (default: a fresh one).
    """

    def __init__(self, node: str, registry: CollectorRegistry | None = None) -> None:
        self.node = node
        self.registry = registry or CollectorRegistry()
        # The standard process_* metrics (CPU seconds, resident memory, open files) of the daemon.
        ProcessCollector(registry=self.registry)
        labels = ("node", "channel")
        self.power = Gauge("hdeem_watch_power_watts", "Latest power of the channel.", labels, registry=self.registry)
        self.energy = Counter(
            "hdeem_watch_energy_joules", "Energy of the channel since the daemon started.", labels, registry=self.registry
        )
        self.samples = Counter(
            "hdeem_watch_samples", "Samples received from the source.", labels, registry=self.registry
        )
        self.missing = Counter(
            "hdeem_watch_missing_samples", "Samples known to be missing (gaps).", labels, registry=self.registry
        )
        self.baseline = Gauge(
            "hdeem_watch_baseline_watts", "Idle baseline power of the channel.", labels, registry=self.registry
        )
        self.runs = Counter("hdeem_watch_runs", "Finished benchmark runs.", ("node",), registry=self.registry)
        self.current = Gauge(
            "hdeem_watch_calibrated_current_amperes", "Calibrated per-device DRAM current.", ("node", "current"),
            registry=self.registry,
        )
        self.error = Gauge(
            "hdeem_watch_calibration_error_ratio", "Mean absolute relative energy error after the fit.", ("node",),
            registry=self.registry,
        )
        self._server: Any = None

    def observe_channel(self, channel: str, *, power_w: float, energy_delta_j: float, samples: int, missing: int) -> None:
        """Update one channel after a poll (non-finite or negative energy deltas are not counted)."""
        self.power.labels(self.node, channel).set(power_w)
        if math.isfinite(energy_delta_j) and energy_delta_j > 0:
            self.energy.labels(self.node, channel).inc(energy_delta_j)
        if samples:
            self.samples.labels(self.node, channel).inc(samples)
        if missing:
            self.missing.labels(self.node, channel).inc(missing)

    def observe_baselines(self, baselines: Mapping[str, float]) -> None:
        """Set the baseline gauges (W by channel)."""
        for channel, power_w in baselines.items():
            self.baseline.labels(self.node, channel).set(power_w)

    def observe_run(self) -> None:
        """Count a finished run."""
        self.runs.labels(self.node).inc()

    def observe_fit(self, fit: Mapping[str, Any] | None) -> None:
        """Set the calibrated currents and error from ``FitResult.to_dict()`` (None clears nothing)."""
        if not fit:
            return
        for name, entry in (fit.get("currents") or {}).items():
            value = entry.get("calibrated") if isinstance(entry, Mapping) else None
            if isinstance(value, int | float):
                self.current.labels(self.node, name).set(float(value))
        after = (fit.get("error") or {}).get("after")
        if isinstance(after, int | float):
            self.error.labels(self.node).set(float(after))

    def serve(self, port: int, addr: str = "127.0.0.1") -> int:
        """Start the HTTP endpoint in a background thread; return the bound port."""
        server, _thread = start_http_server(port, addr=addr, registry=self.registry)
        self._server = server
        return int(server.server_address[1])

    def close(self) -> None:
        """Stop the HTTP endpoint if it runs."""
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None

    def exposition(self) -> bytes:
        """The text exposition format of every metric (what a scrape returns)."""
        return generate_latest(self.registry)
