"""MetricQ metric names and metadata of one node's measurements (pure).

Names follow MetricQ's conventions: lower-case, dot-separated, from the general to the specific,
the quantity as the last segment (``<prefix>.<node>.dram.ab.power``). Metadata uses MetricQ's
standardized fields (``description``, ``unit``, ``rate``, ``scope``, ``quantity``; see
metricq-python ``docs/metadata.rst``).

Example:
    >>> names = MetricNames("hpc.hdeem")
    >>> names.power("node7", "DDR_AB")
    'hpc.hdeem.node7.dram.ab.power'
    >>> names.above_baseline("node7", "DDR_AB")
    'hpc.hdeem.node7.dram.ab.above_baseline.power'
    >>> names.current("node7", "idd4r")
    'hpc.hdeem.node7.dram.calibrated.idd4r.current'
    >>> names.power("n1.cluster", "BLADE")
    'hpc.hdeem.n1_cluster.blade.power'
"""

from __future__ import annotations

import re
from typing import Any

from hdeem_watch.errors import InputError

#: The metric families a source can publish (the ``metrics`` setting chooses among them).
FAMILIES = ("power", "above_baseline", "calibrated_currents")

_SEGMENT = re.compile(r"[^a-z0-9_-]+")
_PREFIX = re.compile(r"^[a-z0-9_-]+(\.[a-z0-9_-]+)*$")
_DRAM_PREFIX = "DDR_"


def segment(text: str) -> str:
    """``text`` as one metric-name segment: lower case, anything but ``[a-z0-9_-]`` as ``_``."""
    return _SEGMENT.sub("_", text.lower()).strip("_") or "_"


def is_dram(channel: str) -> bool:
    """Whether ``channel`` is a DIMM-pair sensor (``DDR_AB`` ...)."""
    return channel.startswith(_DRAM_PREFIX)


def channel_path(channel: str) -> str:
    """The name part of a channel: ``DDR_AB`` → ``dram.ab``, ``BLADE`` → ``blade``."""
    if is_dram(channel):
        return "dram." + segment(channel[len(_DRAM_PREFIX):])
    return segment(channel)


def check_prefix(prefix: str) -> str:
    """Return ``prefix`` if it is a valid MetricQ name prefix.

    Raises:
        InputError: empty, upper case, or characters other than ``[a-z0-9_-]`` and inner dots.
    """
    if not _PREFIX.match(prefix):
        raise InputError(f"metricq prefix {prefix!r}: expected lower-case dot-separated words "
                         "of [a-z0-9_-], e.g. 'taurus.hdeem'")
    return prefix


class MetricNames:
    """Builds the names and the metadata of one site's hdeem-watch metrics.

    Args:
        prefix: the site prefix, e.g. ``"taurus.hdeem"`` (checked by :func:`check_prefix`).
    """

    def __init__(self, prefix: str) -> None:
        self.prefix = check_prefix(prefix)

    def _node(self, node: str) -> str:
        return f"{self.prefix}.{segment(node)}"

    def power(self, node: str, channel: str) -> str:
        """The sensor's power at its native rate."""
        return f"{self._node(node)}.{channel_path(channel)}.power"

    def above_baseline(self, node: str, channel: str) -> str:
        """A DIMM pair's power above its idle baseline."""
        return f"{self._node(node)}.{channel_path(channel)}.above_baseline.power"

    def current(self, node: str, current: str) -> str:
        """One calibrated current (A per device) of the node's DRAM model."""
        return f"{self._node(node)}.dram.calibrated.{segment(current)}.current"

    def group_current(self, node: str, channel: str, current: str) -> str:
        """One calibrated current of a sensor group's own fit (a DIMM pair, or a RAPL socket)."""
        return f"{self._node(node)}.{channel_path(channel)}.calibrated.{segment(current)}.current"

    @staticmethod
    def power_metadata(node: str, channel: str, rate_hz: float) -> dict[str, Any]:
        """Metadata of :meth:`power`: W at the sensor's rate, each value the mean since the last."""
        what = f"DIMM pair {channel[len(_DRAM_PREFIX):]}" if is_dram(channel) else f"sensor {channel}"
        return {
            "description": f"{what} power of node {node} (hdeem-watch, native sensor rate)",
            "unit": "W",
            "rate": float(rate_hz),
            "scope": "last",
            "quantity": "power",
            "node": node,
            "channel": channel,
        }

    @staticmethod
    def above_baseline_metadata(node: str, channel: str, rate_hz: float) -> dict[str, Any]:
        """Metadata of :meth:`above_baseline`."""
        pair = channel[len(_DRAM_PREFIX):] if is_dram(channel) else channel
        return {
            "description": (f"DIMM pair {pair} power of node {node} above its idle baseline "
                            "(hdeem-watch; NaN while no baseline is known)"),
            "unit": "W",
            "rate": float(rate_hz),
            "scope": "last",
            "quantity": "power",
            "node": node,
            "channel": channel,
        }

    @staticmethod
    def current_metadata(node: str, current: str, memspec: str | None, rate_hz: float) -> dict[str, Any]:
        """Metadata of :meth:`current`: valid from its time until the next value."""
        return {
            "description": (f"calibrated DRAM current {current} of node {node}'s power model "
                            f"(hdeem-watch; memspec {memspec or 'unknown'}; A per device, shared by every DIMM pair)"),
            "unit": "A",
            "rate": float(rate_hz),
            "scope": "next",
            "quantity": "current",
            "node": node,
        }

    @staticmethod
    def group_current_metadata(node: str, channel: str, current: str, memspec: str | None,
                               rate_hz: float) -> dict[str, Any]:
        """Metadata of :meth:`group_current`: the fit of that sensor's own energy (aging shows here)."""
        what = f"DIMM pair {channel[len(_DRAM_PREFIX):]}" if is_dram(channel) else f"sensor {channel}"
        return {
            "description": (f"calibrated DRAM current {current} of {what} of node {node} (hdeem-watch; fitted "
                            f"to that sensor's own energy; memspec {memspec or 'unknown'}; A per device)"),
            "unit": "A",
            "rate": float(rate_hz),
            "scope": "next",
            "quantity": "current",
            "node": node,
            "channel": channel,
        }
