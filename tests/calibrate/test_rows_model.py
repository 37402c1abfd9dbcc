"""Calibration rows through the real energy model: stretching, identities, hidden-truth recovery."""

from __future__ import annotations

import numpy as np
import pytest

from hdeem_watch.calibrate import (
    FitOptions,
    fit,
    observation_from_run,
    suggest_next,
)
from hdeem_watch.dram.energy import CURRENT_NAMES, core_energy
from hdeem_watch.dram.stats import CommandStats, RankStats, stretch_stats
from hdeem_watch.errors import InputError


def _measure(truth_spec, spec, stats, window_s, scale=1.0):
    return core_energy(truth_spec, stretch_stats(spec, stats, window_s)).core_j * scale


def test_stretch_keeps_commands_and_scales_residency_and_refresh(samsung, synth) -> None:
    """Stretching to twice the modelled window: same ACT/RD/WR counts, every state's cycles and
    the refreshes doubled, fractions unchanged, cycles_total = window/tCK."""
    stats = synth.kernel_command_stats(samsung, "triad", 8, 0.5)
    out = stretch_stats(samsung, stats, 1.0)
    for before, after in zip(stats.ranks, out.ranks):
        assert after.act == before.act and after.rd == before.rd and after.wr == before.wr
        assert after.cycles_total == pytest.approx(1.0 / samsung.tck_s)
        assert after.ref == pytest.approx(2 * before.ref)
        for name in ("cycles_act", "cycles_pre", "bank_active_cycles"):
            assert getattr(after, name) == pytest.approx(2 * getattr(before, name))


def test_empty_statistics_are_an_idle_precharged_window_with_refresh(samsung) -> None:
    """Statistics with no commands and no window: all ranks precharged standby for the measured
    window, refreshed every REFI; commands in an empty window are an InputError."""
    empty = CommandStats(ranks=(RankStats(), RankStats()))
    out = stretch_stats(samsung, empty, 0.01)
    cycles = 0.01 / samsung.tck_s
    for rank in out.ranks:
        assert rank.cycles_pre == pytest.approx(cycles)
        assert rank.ref == pytest.approx(cycles / samsung.timings["REFI"])
        assert rank.act == 0
    bad = CommandStats(ranks=(RankStats(rd=5), RankStats()))
    with pytest.raises(InputError, match="rank 0 has commands"):
        stretch_stats(samsung, bad, 0.01, name="weird")


def test_row_reproduces_the_model_energy_times_scale(samsung, synth) -> None:
    """columns @ datasheet + constant == core energy of the stretched statistics × scale."""
    stats = synth.kernel_command_stats(samsung, "copy", 12, 0.8, pattern="random")
    obs = observation_from_run(samsung, stats, 1.1, 5.0, scale=4.0, name="copy", time_ns=7)
    currents = np.array([samsung.currents[n] for n in CURRENT_NAMES])
    expected = core_energy(samsung, stretch_stats(samsung, stats, 1.1)).core_j * 4.0
    assert obs.predicted_j(currents) == pytest.approx(expected, rel=1e-12)
    assert obs.time_ns == 7 and obs.window_s == 1.1


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"measured_j": -2.0}, "run 'r1': measured_j"),
    ({"measured_j": float("nan")}, "run 'r1': measured_j"),
    ({"window_s": 0.0}, "run 'r1': window_s"),
    ({"window_s": float("inf")}, "run 'r1': window_s"),
    ({"scale": 0}, "run 'r1': scale"),
])
def test_bad_run_values_name_the_run(samsung, synth, kwargs, message) -> None:
    """A bad energy, window or scale is a one-line InputError naming the run and the field."""
    args = {"window_s": 1.0, "measured_j": 3.0, "scale": 1.0} | kwargs
    stats = synth.idle_stats(samsung, 1.0)
    with pytest.raises(InputError, match=message):
        observation_from_run(samsung, stats, args["window_s"], args["measured_j"], scale=args["scale"], name="r1")


def test_hidden_truth_recovered_exactly_from_varied_model_rows(samsung, synth, paper_truth) -> None:
    """Noise-free energies of a hidden truth (varied kernels, patterns, idle runs, durations,
    windows ≠ model windows, a 4-DIMM scale) plus a per-run offset: all five currents and the
    intercept come back to 1e-6, and the datasheet model overestimated by more than 1.3×."""
    rng = np.random.default_rng(1)
    truth_spec = samsung.with_currents(paper_truth)
    obs = []
    for name, stats, window in synth.realistic_runs(samsung, rng, n_kernel=12, n_idle=2):
        measured = _measure(truth_spec, samsung, stats, window, 4.0) + 0.3
        obs.append(observation_from_run(samsung, stats, window, measured, scale=4.0, name=name))
    result = fit(obs, samsung)
    for name in result.currents:
        assert result.calibrated[name] == pytest.approx(paper_truth[name], rel=1e-6), name
    assert result.intercept_j == pytest.approx(0.3, rel=1e-4)
    before = np.array([r["before_j"] / r["measured_j"] for r in result.runs])
    assert before.mean() > 1.3
    assert result.error_after < 1e-8


def test_vpp_current_can_be_calibrated_and_collinear_pair_is_flagged(samsung, synth) -> None:
    """Any memspec current may be chosen: IPP0 (VPP domain) is recovered when calibrated in place
    of IDD0; calibrating both, whose columns are proportional (both scale with ACT), is reported
    rank-deficient with neither flagged identifiable."""
    rng = np.random.default_rng(2)
    truth = {"idd2n": samsung.currents["idd2n"] * 0.6, "ipp0": samsung.currents["ipp0"] * 0.5,
             "idd3n": samsung.currents["idd3n"] * 0.4}
    truth_spec = samsung.with_currents(truth)
    obs = [observation_from_run(samsung, s, w, _measure(truth_spec, samsung, s, w), name=n)
           for n, s, w in synth.realistic_runs(samsung, rng, n_kernel=10, n_idle=2)]
    alone = fit(obs, samsung, FitOptions(currents=("ipp0", "idd2n", "idd3n"), intercept=False))
    assert alone.calibrated["ipp0"] == pytest.approx(truth["ipp0"], rel=1e-6)
    both = fit(obs, samsung, FitOptions(currents=("idd0", "ipp0", "idd2n", "idd3n"), intercept=False))
    assert both.status == "rank-deficient"
    assert not both.identifiable[0] and not both.identifiable[1]
    with pytest.raises(InputError, match="unknown current 'idd7'"):
        fit(obs, samsung, FitOptions(currents=("idd0", "idd7")))


def test_suggest_next_picks_the_run_that_determines_the_weak_current(samsung, synth, paper_truth) -> None:
    """After read-only and idle runs IDD4W is the weakest current; among candidate runs a
    write kernel removes most of its variance, a read kernel almost none."""
    truth_spec = samsung.with_currents(paper_truth)
    obs = []
    for i, threads in enumerate([1, 2, 4, 8, 12, 24, 3, 6]):
        for pattern in ("stream", "random"):
            stats = synth.kernel_command_stats(samsung, "read", threads, 1.0 + 0.1 * i, pattern=pattern)
            obs.append(observation_from_run(samsung, stats, 1.0 + 0.1 * i,
                                            _measure(truth_spec, samsung, stats, 1.0 + 0.1 * i),
                                            name=f"read-{threads}-{pattern}"))
    idle = synth.idle_stats(samsung, 2.0)
    obs.append(observation_from_run(samsung, idle, 2.0, _measure(truth_spec, samsung, idle, 2.0), name="idle"))
    result = fit(obs, samsung)
    assert not result.identifiable[result.currents.index("idd4w")]
    candidates = {
        "read-24": synth.kernel_command_stats(samsung, "read", 24, 1.0),
        "assign-nt-24": synth.kernel_command_stats(samsung, "assign-nt", 24, 1.0),
        "copy-8": synth.kernel_command_stats(samsung, "copy", 8, 1.0),
        "idle": synth.idle_stats(samsung, 1.0),
    }
    ranking = suggest_next(result, candidates)
    scores = dict(ranking)
    assert ranking[0][0] == "assign-nt-24"
    assert scores["assign-nt-24"] > 0.9
    assert scores["read-24"] < 0.05 and scores["idle"] < 0.05
    assert [s for _, s in ranking] == sorted(scores.values(), reverse=True)
    with pytest.raises(InputError, match="no candidate"):
        suggest_next(result, {})
