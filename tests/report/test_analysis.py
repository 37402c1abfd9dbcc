"""The numbers behind the figures: grouping, drift alarms, energy by component, --since/--group."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from hdeem_watch.errors import InputError
from hdeem_watch.fit_record import FitRecord
from hdeem_watch.report import analysis
from hdeem_watch.report.records import FitEntry, RunRow
from hdeem_watch.report.state_reader import read_state


def _fit(value_a: float, low_a: float, high_a: float, identifiable: bool = True) -> FitRecord:
    return FitRecord.from_dict({"currents": {"idd3n": {"calibrated": value_a, "ci95": [low_a, high_a],
                                                       "identifiable": identifiable}}})


def test_drift_flags_follow_the_calibrators_rule() -> None:
    """A current is flagged when it leaves the 95 % interval of the newest fit at least the lag
    earlier, both fits determining it; fits younger than the lag have no reference."""
    hour = 3600 * 10**9
    history = [FitEntry(0, "r1", _fit(0.030, 0.029, 0.031)),
               FitEntry(hour // 2, "r2", _fit(0.040, 0.039, 0.041)),  # moved, but no reference 1 h back
               FitEntry(2 * hour, "r3", _fit(0.0400, 0.0395, 0.0405)),  # inside r2's interval
               FitEntry(3 * hour, "r4", _fit(0.036, 0.035, 0.037)),    # outside r3's interval
               FitEntry(4 * hour, "r5", _fit(0.050, 0.049, 0.051, identifiable=False))]
    flags = analysis.drift_flags(history, lag_s=3600.0)
    assert [f.get("idd3n", False) for f in flags] == [False, False, False, True, False]
    assert all(not any(f.values()) for f in analysis.drift_flags(history, lag_s=None))


def test_energy_groups_average_runs_of_one_kernel_and_thread_count() -> None:
    """Runs of the same kernel and threads are averaged; idle runs form one group whatever their threads."""
    runs = [RunRow("r1", "idle", "idle", 24, 1, 4.0, 10.0, 20.0, 10.5),
            RunRow("r2", "idle", "idle", 1, 2, 4.0, 12.0, 22.0, 11.5),
            RunRow("r3", "triad-24t", "triad", 24, 3, 2.0, 8.0, 16.0, 8.8)]
    groups = analysis.energy_groups(runs)
    assert [(g.label, g.n) for g in groups] == [("idle", 2), ("triad 24t", 1)]
    assert groups[0].measured_j == 11.0 and groups[0].datasheet_error_pct == pytest.approx(1000 / 11)
    assert groups[1].calibrated_error_pct == pytest.approx(10.0)


def test_components_sum_to_the_calibrated_model_energy(state_dir: Path) -> None:
    """Re-modelling each kernel's run the way the daemon does gives components (with the fit's
    intercept) that add up to the calibrated-model energy of that run."""
    data = read_state(state_dir)
    chosen = analysis.representative_runs(data.runs)
    assert [r.kernel for r in chosen] == ["idle", "add", "assign", "copy", "read", "scale", "selfscale", "triad"]
    for run in chosen:
        parts = analysis.component_energies(data.spec, data.fit, run)
        assert sum(parts.values()) == pytest.approx(run.calibrated_j, rel=1e-9)
        assert parts["refresh"] > 0 and parts["background"] > 0
        if run.kernel == "idle":
            assert parts["RD"] == parts["WR"] == parts["ACT/PRE"] == 0
        elif run.kernel == "read":
            assert parts["RD"] > 0 and parts["WR"] == 0
        else:
            assert parts["WR"] > 0


def test_parse_since_ages_and_dates() -> None:
    """Ages count back from now; dates without an offset are UTC; anything else is bad input."""
    now = 1_800_000_000 * 10**9
    assert analysis.parse_since("90m", now) == now - 90 * 60 * 10**9
    assert analysis.parse_since("7d", now) == now - 7 * 86400 * 10**9
    assert analysis.parse_since("2026-11-25", now) == 1795564800 * 10**9
    assert analysis.parse_since("2026-11-25T01:00+01:00", now) == 1795564800 * 10**9
    with pytest.raises(InputError, match="--since 'last week'"):
        analysis.parse_since("last week", now)


def test_select_since_and_group(state_dir: Path) -> None:
    """--since keeps what ended at or after T; --group keeps one pair's baselines; an unknown group
    is bad input listing the known ones."""
    data = read_state(state_dir)
    cut = data.runs[10].t_ns
    late = analysis.select(data, since_ns=cut)
    assert [r.run_id for r in late.runs] == [r.run_id for r in data.runs[10:]]
    assert all(h.t_ns >= cut for h in late.fit_history) and late.fit == data.fit
    pair = analysis.select(data, group="DDR_EF")
    assert {b.channel for b in pair.baselines} == {"DDR_EF"} and pair.channels == ("DDR_EF",)
    assert analysis.select(data, group="node").baselines == data.baselines
    with pytest.raises(InputError, match="DDR_AB, DDR_CD"):
        analysis.select(data, group="DDR_ZZ")


def test_model_currents_take_the_datasheet_where_the_fit_has_nothing(state_dir: Path) -> None:
    """Calibrated currents replace the datasheet's; the rest (IPP*, IDD5B, ...) stay the datasheet's."""
    from hdeem_watch.dram.energy import CURRENT_NAMES

    data = read_state(state_dir)
    vector, intercept = analysis.model_currents(data.spec, data.fit)
    values = dict(zip(CURRENT_NAMES, vector))
    assert values["idd3n"] == data.fit.currents["idd3n"].calibrated_a
    assert values["ipp3n"] == data.spec.currents["ipp3n"]
    assert intercept == data.fit.intercept_j and math.isfinite(intercept)
