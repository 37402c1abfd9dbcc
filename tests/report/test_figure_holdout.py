"""The held-out figure (issue #32): hold-out runs grouped by kernel and thread count with the
calibrated model's prediction from before each run; without hold-out runs one clear panel."""

from __future__ import annotations

import math

import pytest

from hdeem_watch.report.analysis import holdout_groups
from hdeem_watch.report.figures_holdout import holdout_figure
from hdeem_watch.report.records import ReportData, RunRow

pytest.importorskip("matplotlib")


def _run(i: int, kernel: str, threads: int, measured: float, datasheet: float, predicted: float) -> RunRow:
    return RunRow(run_id=f"r{i}", name=f"{kernel}-{threads}t", kernel=kernel, threads=threads, t_ns=i,
                  window_s=1.5, measured_j=measured, datasheet_j=datasheet, calibrated_j=math.nan,
                  predicted_j=predicted)


def test_hold_out_runs_are_grouped_and_predicted_from_before() -> None:
    runs = (_run(1, "read", 24, 20.0, 30.0, 21.0), _run(2, "gups", 24, 40.0, 60.0, 41.0),
            _run(3, "gups", 24, 42.0, 60.0, 41.0), _run(4, "stride4", 1, 10.0, 16.0, 9.5),
            _run(5, "chase", 4, 12.0, 18.0, math.nan))  # no fit before it: not shown
    groups = holdout_groups(runs)
    assert [(g.kernel, g.threads, g.n) for g in groups] == [("gups", 24, 2), ("stride4", 1, 1)]
    assert groups[0].calibrated_error_pct == pytest.approx(100 * (41.0 / 41.0 - 1)) and \
        groups[1].calibrated_error_pct == pytest.approx(-5.0)
    drawn = holdout_figure(ReportData(source="test", spec=None, runs=runs, fit=None))
    assert drawn.key == "fig7-holdout" and not drawn.missing
    table = next(iter(drawn.tables.values()))
    assert [row[0] for row in table.rows] == ["gups", "stride4"]


def test_without_hold_out_runs_the_figure_says_so() -> None:
    drawn = holdout_figure(ReportData(source="test", spec=None, runs=(_run(1, "read", 24, 20.0, 30.0, 21.0),),
                                      fit=None))
    assert drawn.missing == ("hold-out runs",) and not drawn.tables
