"""Draw every figure of a report and write the page and the files (the one I/O shell of the package).

Files in the output directory: ``index.html`` (self-contained), one file per figure in the chosen
format (``fig1-energy.png`` ...; none for ``html``), ``numbers.json`` (every figure's tables) and
``memspec-calibrated.json`` (when there is a calibration).

Example::

    from hdeem_watch.report.state_reader import read_state
    written = build_report(read_state("state/"), "report/", fmt="png")
    written = write_report(state_dir="state/", since="7d", out="report/")   # read, select and build in one call
    written.page       # Path('report/index.html')
"""

from __future__ import annotations

import io
import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hdeem_watch.errors import InputError
from hdeem_watch.report.figure import ReportFigure
from hdeem_watch.report.figures_holdout import holdout_figure
from hdeem_watch.report.figures_model import (
    calibrated_memspec,
    components_figure,
    currents_figure,
    energy_figure,
)
from hdeem_watch.report.figures_time import aging_figure, jobs_figure, residuals_figure
from hdeem_watch.report.page import render_page
from hdeem_watch.report.records import ReportData
from hdeem_watch.report.style import pyplot

#: Formats of the figure files (``html``: the page only).
FORMATS = ("html", "png", "svg", "pdf")
#: The figure builders, in page order.
BUILDERS: tuple[Callable[[ReportData], ReportFigure], ...] = (
    energy_figure, currents_figure, residuals_figure, aging_figure, components_figure, jobs_figure, holdout_figure)


@dataclass(frozen=True)
class WrittenReport:
    """What :func:`build_report` wrote.

    Attributes:
        page: the HTML page.
        figures: the figure files (empty for ``html``).
        numbers: ``numbers.json``.
        memspec: ``memspec-calibrated.json`` (None without a calibration).
        missing: per figure key, what it had no data for.
        notes: per figure key, caveats about what it drew.
    """

    page: Path
    figures: tuple[Path, ...]
    numbers: Path
    memspec: Path | None
    missing: dict[str, tuple[str, ...]]
    notes: dict[str, tuple[str, ...]] = field(default_factory=dict)


def build_report(data: ReportData, out_dir: str | Path, *, fmt: str = "png",
                 clock: Callable[[], float] = time.time) -> WrittenReport:
    """Draw the figures of ``data`` and write the report into ``out_dir`` (created if missing).

    Args:
        data: what to show.
        out_dir: the output directory.
        fmt: format of the figure files, one of :data:`FORMATS`.
        clock: wall clock (s) for the "drawn at" line.

    Raises:
        InputError: an unknown format or an output directory that cannot be written.
        MissingPlotting: matplotlib is not installed.
    """
    if fmt not in FORMATS:
        raise InputError(f"--format {fmt!r}: expected one of {', '.join(FORMATS)}")
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise InputError(f"--out {out}: cannot create the directory: {error.strerror or error}") from None
    plt = pyplot()
    figures: list[dict[str, Any]] = []
    tables = {}
    files: list[Path] = []
    try:
        for builder in BUILDERS:
            drawn = builder(data)
            try:
                svg = io.BytesIO()
                drawn.figure.savefig(svg, format="svg")
                if fmt != "html":
                    path = out / f"{drawn.key}.{fmt}"
                    if fmt == "svg":  # the page's own drawing: the same bytes, not drawn twice
                        path.write_bytes(svg.getvalue())
                    else:
                        drawn.figure.savefig(path, format=fmt)
                    files.append(path)
            finally:
                plt.close(drawn.figure)
            figures.append({"key": drawn.key, "title": drawn.title, "how_to_read": drawn.how_to_read,
                            "svg": svg.getvalue(), "missing": drawn.missing, "notes": drawn.notes})
            tables[drawn.title] = drawn.tables
        memspec = calibrated_memspec(data)
        generated = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(clock()))
        page = out / "index.html"
        page.write_text(render_page("hdeem-watch report", data.source, figures, tables, memspec,
                                    notes=data.notes, generated=generated), encoding="utf-8")
        numbers = out / "numbers.json"
        numbers.write_text(json.dumps(_numbers(tables), indent=1, allow_nan=False) + "\n", encoding="utf-8")
        memspec_path = None
        if memspec is not None:
            memspec_path = out / "memspec-calibrated.json"
            memspec_path.write_text(json.dumps(memspec, indent=2) + "\n", encoding="utf-8")
    except OSError as error:
        raise InputError(f"--out {out}: cannot write the report: {error.strerror or error}") from None
    return WrittenReport(page=page, figures=tuple(files), numbers=numbers, memspec=memspec_path,
                         missing={f["key"]: tuple(f["missing"]) for f in figures},
                         notes={f["key"]: tuple(f["notes"]) for f in figures})


def _numbers(tables: dict[str, Any]) -> dict[str, Any]:
    """Every table as JSON (NaN as null)."""
    import math

    def cell(value: Any) -> Any:
        if isinstance(value, float) and not math.isfinite(value):
            return None
        if hasattr(value, "item"):  # numpy scalars
            return cell(value.item())
        return value

    return {title: {caption: {"columns": list(t.columns), "rows": [[cell(v) for v in row] for row in t.rows]}
                    for caption, t in captioned.items()} for title, captioned in tables.items()}


def write_report(*, state_dir: str | None = None, runs: str | None = None, since: str | None = None,
                 group: str | None = None, out: str = "hdeem-watch-report", fmt: str = "png",
                 now_ns: int | None = None) -> WrittenReport:
    """Read a state (``state_dir``; default the daemon's) or a RUNS.json (``runs``), keep what
    ``since``/``group`` select, draw and write into ``out`` (``hdeem-watch report``, ``demo --report``).

    Raises:
        InputError: bad input (a missing state, a malformed RUNS.json, a bad --since or --group).
        MissingPlotting: matplotlib is not installed.
    """
    from hdeem_watch.report.analysis import parse_since, select

    if runs is not None:
        from hdeem_watch.report.runs_reader import read_runs

        data = read_runs(runs)
    else:
        from hdeem_watch.config import default_state_dir
        from hdeem_watch.report.state_reader import read_state

        data = read_state(state_dir or default_state_dir())
    since_ns = parse_since(since, time.time_ns() if now_ns is None else now_ns) if since else None
    return build_report(select(data, since_ns=since_ns, group=group), out, fmt=fmt)
