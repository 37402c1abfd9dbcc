"""The daemon's stream messages as MetricQ data points (pure: no sockets, no clock).

:class:`StreamTranslator` turns each decoded :class:`~hdeem_watch.wire.protocol.Message` into
:class:`Points` (one metric, many times and values) and tells which metrics are new, with their
metadata, so that the source declares them before their first value:

* ``samples/<channel>`` → the sensor's power at its native rate, and for a DIMM pair its power
  above the latest ``baseline`` (NaN while no baseline is known);
* ``baseline`` → remembered per node and channel;
* ``calib`` → the calibrated currents of the node's fit and of each sensor group's own fit (a
  DIMM pair's: where its aging shows), one slow value each, at the message's time;
* ``status``, ``run`` → nothing.

MetricQ needs strictly increasing times per metric; a value at or before the last one sent for its
metric (a daemon restarted with a clock behind the previous run, a re-published ``calib``) is left
out and counted in :attr:`StreamTranslator.out_of_order`.

Example:
    >>> import numpy as np
    >>> from hdeem_watch.wire import protocol
    >>> from hdeem_watch.metricq.naming import MetricNames
    >>> tr = StreamTranslator(MetricNames("site"))
    >>> frames = protocol.encode_samples("n1", "DDR_AB", seq=1, rate_hz=100.0, t_wall_ns=np.array([10, 20]),
    ...                                  power_w=np.array([2.0, 3.0]), energy_j=1.0, status="ok")
    >>> out = tr.translate(protocol.decode(frames))
    >>> sorted(out.declarations)
    ['site.n1.dram.ab.above_baseline.power', 'site.n1.dram.ab.power']
    >>> [(p.metric, p.values.tolist()) for p in out.points][0]
    ('site.n1.dram.ab.power', [2.0, 3.0])
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hdeem_watch.fit_record import FitRecord
from hdeem_watch.metricq.naming import FAMILIES, MetricNames, is_dram
from hdeem_watch.wire.protocol import Message

#: The rate declared for the calibrated currents: the daemon re-publishes ``calib`` every 10 s.
CALIB_RATE_HZ = 0.1


@dataclass(frozen=True)
class Points:
    """Values of one metric: ``t_ns`` (int64, ns since the epoch, increasing) and ``values`` (float64)."""

    metric: str
    t_ns: np.ndarray
    values: np.ndarray

    def __len__(self) -> int:
        return int(self.t_ns.size)


@dataclass
class Translation:
    """What one message becomes: metrics to declare first (name → metadata), then points."""

    declarations: dict[str, dict[str, Any]] = field(default_factory=dict)
    points: list[Points] = field(default_factory=list)


class StreamTranslator:
    """Stateful translator of one source's stream (every node it subscribes to).

    Args:
        names: the metric names and metadata of the site.
        families: which metric families to publish (a subset of
            :data:`~hdeem_watch.metricq.naming.FAMILIES`).
    """

    def __init__(self, names: MetricNames, families: Collection[str] = FAMILIES) -> None:
        unknown = set(families) - set(FAMILIES)
        if unknown:
            raise ValueError(f"unknown metric families {sorted(unknown)}; expected some of {list(FAMILIES)}")
        self.names = names
        self.families = frozenset(families)
        self.declared: dict[str, dict[str, Any]] = {}
        self.baseline_w: dict[tuple[str, str], float] = {}
        self.out_of_order = 0
        self._last_t: dict[str, int] = {}

    def translate(self, message: Message) -> Translation:
        """The declarations and points of ``message`` (an empty translation for other kinds)."""
        out = Translation()
        if message.kind == "samples" and message.channel is not None:
            self._samples(message, message.channel, out)
        elif message.kind == "baseline":
            self._baseline(message)
        elif message.kind == "calib" and "calibrated_currents" in self.families:
            self._calib(message, out)
        return out

    def forget_declarations(self) -> None:
        """Forget what was declared (a new connection to MetricQ declares everything again)."""
        self.declared.clear()

    def _declare(self, out: Translation, metric: str, metadata: dict[str, Any]) -> None:
        if self.declared.get(metric) != metadata:
            self.declared[metric] = metadata
            out.declarations[metric] = metadata

    def _add(self, out: Translation, metric: str, t_ns: np.ndarray, values: np.ndarray) -> None:
        last = self._last_t.get(metric)
        if last is not None and t_ns.size and t_ns[0] <= last:
            keep = t_ns > last
            self.out_of_order += int(t_ns.size - np.count_nonzero(keep))
            t_ns, values = t_ns[keep], values[keep]
        if t_ns.size and np.any(np.diff(t_ns) <= 0):  # never from the daemon; guard anyway
            keep = np.concatenate(([True], np.diff(t_ns) > 0))
            self.out_of_order += int(t_ns.size - np.count_nonzero(keep))
            t_ns, values = t_ns[keep], values[keep]
        if t_ns.size:
            self._last_t[metric] = int(t_ns[-1])
            out.points.append(Points(metric, t_ns, values))

    def _samples(self, message: Message, channel: str, out: Translation) -> None:
        t_ns, power_w = message.samples()
        if t_ns.size == 0:
            return
        node = message.node
        rate = float(message.header.get("rate_hz") or 0.0)
        if "power" in self.families:
            metric = self.names.power(node, channel)
            self._declare(out, metric, self.names.power_metadata(node, channel, rate))
            self._add(out, metric, t_ns, power_w)
        if "above_baseline" in self.families and is_dram(channel):
            metric = self.names.above_baseline(node, channel)
            self._declare(out, metric, self.names.above_baseline_metadata(node, channel, rate))
            baseline = self.baseline_w.get((node, channel), math.nan)
            self._add(out, metric, t_ns, power_w - baseline)

    def _baseline(self, message: Message) -> None:
        channels = message.header.get("channels")
        if not isinstance(channels, Mapping):
            return
        for channel, entry in channels.items():
            power = entry.get("power_w") if isinstance(entry, Mapping) else None
            key = (message.node, str(channel))
            if isinstance(power, (int, float)) and not isinstance(power, bool) and math.isfinite(power):
                self.baseline_w[key] = float(power)
            else:
                self.baseline_w.pop(key, None)

    def _calib(self, message: Message, out: Translation) -> None:
        memspec = message.header.get("memspec")
        spec_name = memspec if isinstance(memspec, str) else None
        node = message.node
        for name, amps in _calibrated(message.header.get("fit")):
            metric = self.names.current(node, name)
            self._declare(out, metric, self.names.current_metadata(node, name, spec_name, CALIB_RATE_HZ))
            self._add(out, metric, np.array([message.t_ns], dtype=np.int64), np.array([amps]))
        groups = message.header.get("groups")
        for channel, entry in sorted(groups.items()) if isinstance(groups, Mapping) else ():
            for name, amps in _calibrated(entry.get("fit") if isinstance(entry, Mapping) else None):
                metric = self.names.group_current(node, str(channel), name)
                self._declare(out, metric, self.names.group_current_metadata(node, str(channel), name, spec_name,
                                                                             CALIB_RATE_HZ))
                self._add(out, metric, np.array([message.t_ns], dtype=np.int64), np.array([amps]))


def _calibrated(fit: Any) -> list[tuple[str, float]]:
    """``(current, A)`` of a fit's calibrated currents, NaN where unknown (never 0); none without a fit."""
    if not isinstance(fit, Mapping):
        return []
    return [(name, entry.calibrated_a) for name, entry in sorted(FitRecord.from_dict(fit).currents.items())]
