"""What the daemon tells the world: heartbeat, calibration, baselines, Prometheus metrics.

Bound to one :class:`~hdeem_watch.daemon.service.Daemon` (it reads the daemon's source, accounts,
windows, publisher, store and settings): the status body and heartbeat, the ``calib`` body with the
simulated source's truth, and the baselines — merging new ones (idle windows, quiet periods),
storing and publishing them.
"""

from __future__ import annotations

import math
import os
from typing import TYPE_CHECKING, Any

from hdeem_watch.daemon import baselines as bl

if TYPE_CHECKING:
    from hdeem_watch.daemon.service import Daemon


class Reporter:
    """Heartbeat, calibration and baseline publishing of one daemon.

    Args:
        daemon: the daemon whose state it reports.
    """

    def __init__(self, daemon: Daemon) -> None:
        self.d = daemon

    def status_body(self) -> dict[str, Any]:
        """The heartbeat body (also the base of the ``status`` op)."""
        try:
            health = str(self.d.source.health())
        except Exception as error:
            health = f"error: {error}"
        if self.d._last_health.startswith("error") and health == "ok":
            health = self.d._last_health
        memory = self.d._process.memory_info()
        run = next((w.context.get("record") for w in self.d.windows if w.kind == "run"), None)
        return {
            "source": {"kind": getattr(self.d.source, "kind", self.d.settings.source), "health": health},
            "channels": {name: a.status_entry() for name, a in self.d.accounts.items()},
            "process": {"cpu_percent": self.d._cpu_percent, "rss_bytes": int(memory.rss), "pid": os.getpid()},
            "run": run,
            "uptime_s": (self.d.clock() - self.d._t_open_mono) / 1e9,
            "endpoints": {"pub": self.d.pub_endpoint, "control": self.d.control_endpoint},
            "curve_public_key": None if self.d.curve is None else self.d.curve.public.decode(),
            "speed": self.d.speed,
            "poll_interval_s": self.d.poll_interval_ns / 1e9,
            "prometheus_port": self.d.metrics_port,
        }

    def publish_status(self) -> None:
        """Publish the heartbeat (and update the Prometheus metrics once a second)."""
        assert self.d.publisher is not None
        self.d._cpu_percent = float(self.d._process.cpu_percent(None))
        self.d._last_health = "ok" if self.d.poll_errors == 0 else self.d._last_health
        for account in self.d.accounts.values():
            account.close_rate_window()
        self.d.publisher.publish("status", self.status_body())
        if self.d.recorder is not None:
            self.d.recorder.flush()
        if self.d.metrics is not None:
            for name, account in self.d.accounts.items():
                energy0, samples0, gaps0 = self.d._metric_last.get(name, (0.0, 0, 0))
                energy = account.energy_j
                self.d.metrics.observe_channel(name, power_w=account.power_w, energy_delta_j=energy - energy0,
                                             samples=account.samples - samples0, missing=account.gaps - gaps0)
                self.d._metric_last[name] = (energy if math.isfinite(energy) else energy0, account.samples,
                                           account.gaps)
        self.d.poll_errors = 0

    def truth(self) -> dict[str, Any] | None:
        """The simulated source's hidden truth, or None for real sensors."""
        getter = getattr(self.d.source, "truth", None)
        if getter is None:
            return None
        try:
            return dict(getter())
        except Exception:
            return None

    def publish_calib(self) -> None:
        """Publish the ``calib`` body (cached by the publisher for late joiners)."""
        if self.d.publisher is not None:
            self.d.publisher.publish("calib", self.calib_with_truth())

    def calib_with_truth(self) -> dict[str, Any]:
        """The latest ``calib`` body with the sim's truth now."""
        body = dict(self.d.calib_body)
        body["truth"] = self.truth()
        return body

    def publish_baselines(self) -> None:
        """Publish the ``baseline`` body (cached for late joiners)."""
        if self.d.publisher is not None:
            self.d.publisher.publish("baseline", bl.baselines_body(self.d.baselines))
        if self.d.metrics is not None:
            self.d.metrics.observe_baselines({c: b.power_w for c, b in self.d.baselines.items()})

    def update_baseline(self, channel: str, baseline: bl.Baseline) -> bool:
        """Merge a new baseline; store it if it was kept. Returns whether it changed."""
        kept = bl.merge(self.d.baselines.get(channel), baseline)
        if kept is self.d.baselines.get(channel):
            return False
        self.d.baselines[channel] = kept
        if self.d.store is not None:
            self.d.store.save_baseline(channel, kept.to_dict())
        return True

    def look_for_quiet_periods(self) -> None:
        """Baselines from quiet periods of the recent samples (only while no window is open)."""
        if self.d.windows:
            return
        changed = False
        for name in self.d.dram_channels:
            account = self.d.accounts[name]
            ring = account.history
            if ring is None or len(ring) == 0:
                continue
            values = ring.values()
            found = bl.quiet_window(values, rate_hz=account.rate_hz, window_s=self.d.settings.quiet_window_s,
                                    max_spread_w=self.d.settings.quiet_max_spread_w)
            if found is None:
                continue
            baseline = bl.baseline_from_samples(values[found[0]:found[1]], t_ns=account.last_t_ns or 0,
                                                origin="quiet")
            changed |= self.update_baseline(name, baseline)
        if changed:
            self.publish_baselines()

