"""Model functions the report uses whose home is moving (issue 13's layering): imported from
wherever this version keeps them, so the report works before and after the move.

- :func:`stretch_stats`: ``dram.stats`` after the move, ``calibrate.rows`` before;
- :func:`trace_stats`: ``dram.trace_state`` after the move, ``dram.command_trace`` before.

Example:
    >>> from hdeem_watch.dram.memspec import preset
    >>> from hdeem_watch.dram.stats import CommandStats, RankStats
    >>> spec = preset("ddr4-2133-x8-4gb")
    >>> idle = CommandStats(ranks=(RankStats(), RankStats()))
    >>> stretch_stats(spec, idle, 1e-3).ranks[0].cycles_pre == 1e-3 / spec.tck_s
    True
"""

from __future__ import annotations

try:
    from hdeem_watch.dram.stats import stretch_stats  # type: ignore[attr-defined,unused-ignore]
except ImportError:
    from hdeem_watch.calibrate.rows import stretch_stats  # type: ignore[no-redef,unused-ignore]
try:
    from hdeem_watch.dram.trace_state import trace_stats  # type: ignore[attr-defined,unused-ignore]
except ImportError:
    from hdeem_watch.dram.command_trace import trace_stats  # type: ignore[no-redef,unused-ignore]

__all__ = ["stretch_stats", "trace_stats"]
