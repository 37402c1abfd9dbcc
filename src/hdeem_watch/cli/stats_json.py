"""The ``--json`` summary of command statistics that ``model stats`` and ``model kernel`` print, for
DDR4 (cli/model_stats.py) and DDR5 (cli/model_stats_ddr5.py) alike."""

from __future__ import annotations

from typing import Any

from hdeem_watch.dram.stats import CommandStats


def summary(stats: CommandStats, *, requests: float, reads: float, writes: float, row_hits: float | None,
            row_misses: float | None, row_conflicts: float | None, cycles: float) -> dict[str, Any]:
    """The ``--json`` keys of DESIGN.md section 7 (pure)."""
    return {
        "requests": requests, "reads": reads, "writes": writes,
        "act": stats.total("act"), "pre": stats.total("pre"), "ref": stats.total("ref"),
        "rd": stats.total("rd") + stats.total("rda"), "wr": stats.total("wr") + stats.total("wra"),
        "row_hits": row_hits, "row_misses": row_misses, "row_conflicts": row_conflicts,
        "cycles": cycles, "ranks": [rank.to_dict() for rank in stats.ranks],
    }
