"""The ordering rules as linear forms: the same rules the memspec check applies, sorted into
bounds and couplings against the calibrated currents, and a fit that keeps the couplings."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hdeem_watch.calibrate import observation_from_run
from hdeem_watch.calibrate.fit import FitOptions, fit
from hdeem_watch.calibrate.physical import ordering_rules, physical_limits
from hdeem_watch.dram.energy import core_energy
from hdeem_watch.dram.memspec import load_memspec, preset
from hdeem_watch.dram.memspec_check import physical_violations
from hdeem_watch.dram.presets import PRESETS
from hdeem_watch.dram.stats import stretch_stats

VDD = ("idd0", "idd2n", "idd3n", "idd4r", "idd4w", "idd2p", "idd3p", "idd5b")


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_the_linear_forms_break_exactly_where_the_memspec_check_does(name: str) -> None:
    """Currents scattered ±60 % around each preset: the rules whose form is negative are, by name
    and in order, the rules :func:`physical_violations` reports."""
    spec = preset(name)
    rng = np.random.default_rng(len(name))
    for _ in range(40):
        scattered = spec.with_currents({c: spec.currents[c] * rng.uniform(0.4, 1.6) for c in VDD})
        broken = [rule.rule for rule in ordering_rules(scattered)
                  if sum(f * scattered.currents[c] for c, f in rule.coefficients.items()) < -1e-12]
        assert broken == [v.split(":")[0] for v in physical_violations(scattered)]


def test_rules_sort_into_bounds_and_couplings() -> None:
    """Calibrating IDD0, IDD2N, IDD3N: IDD2N ≥ IDD2P is a bound, IDD3N ≥ IDD2N a coupling whose
    other currents are calibrated too (floor 0), IDD4R ≥ IDD3N an upper bound on IDD3N."""
    spec = preset("samsung-m393a1g43db0-cpb")
    chosen = ("idd0", "idd2n", "idd3n")
    limits = physical_limits(spec, chosen)
    assert limits.bounds["idd2n"][0] == pytest.approx(spec.currents["idd2p"])
    assert limits.bounds["idd3n"][1] == pytest.approx(min(spec.currents[c] for c in ("idd4r", "idd4w", "idd5b")))
    background = next(c for c in limits.couplings if c.rule == "background")
    assert background.coefficients == (0.0, -1.0, 1.0) and background.floor_a == 0.0
    assert {c.rule for c in limits.couplings} == {"activation", "precharge", "ACT+PRE", "background"}


def _paper_runs(synth, samsung, paper_truth):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(1)
    truth_spec = samsung.with_currents(paper_truth)
    return [observation_from_run(samsung, stats, window,
                                 core_energy(truth_spec, stretch_stats(samsung, stats, window)).core_j * 4 + 0.3,
                                 scale=4.0, name=name)
            for name, stats, window in synth.realistic_runs(samsung, rng, n_kernel=12, n_idle=2)]


def test_a_fit_with_rules_is_physical_and_says_what_it_held(synth, samsung, paper_truth) -> None:
    """The seed paper's calibrated currents break IDD3N ≥ IDD2N. Fitted as measured they come
    back exactly (and unphysical); with ``rules=True`` the fit keeps IDD3N = IDD2N, names the rule,
    is physical, and pays for it in error."""
    assert any(v.startswith("background") for v in physical_violations(samsung.with_currents(paper_truth)))
    runs = _paper_runs(synth, samsung, paper_truth)
    measured = fit(runs, samsung)
    held = fit(runs, samsung, FitOptions(rules=True))
    assert measured.calibrated["idd3n"] == pytest.approx(paper_truth["idd3n"], rel=1e-6)
    assert measured.rules_held == () and measured.status == "ok"
    assert held.rules_held == ("background",) and held.status == "at-bound"
    assert held.calibrated["idd3n"] == pytest.approx(held.calibrated["idd2n"], rel=1e-9)
    assert physical_violations(samsung.with_currents(held.calibrated)) == []
    assert held.error_after > measured.error_after + 1e-3
    assert held.dof == measured.dof + 1
    assert held.to_dict()["rules_held"] == ["background"]


def test_cli_physical_rules_writes_a_memspec_that_loads(tmp_path, synth, samsung, paper_truth, capsys) -> None:
    """``calibrate --physical-rules --write-memspec``: a memspec that loads without
    --allow-unphysical, the rule held in the JSON and in the table."""
    from hdeem_watch.cli import main
    from hdeem_watch.dram.memspec import save_memspec

    save_memspec(samsung, tmp_path / "M.json")
    runs = [{"name": obs.name, "measured_j": obs.measured_j, "stats": stats.to_dict(), "window_s": window,
             "scale": 4}
            for obs, (_, stats, window) in zip(_paper_runs(synth, samsung, paper_truth),
                                              synth.realistic_runs(samsung, np.random.default_rng(1), n_kernel=12,
                                                                   n_idle=2))]
    (tmp_path / "RUNS.json").write_text(json.dumps({"memspec": "M.json", "runs": runs}))
    out = tmp_path / "physical.json"
    assert main(["calibrate", "--runs", str(tmp_path / "RUNS.json"), "--physical-rules", "--json",
                 "--write-memspec", str(out)]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["physical"] is True and data["rules_held"] == ["background"]
    loaded = load_memspec(out)
    assert loaded.currents["idd3n"] == pytest.approx(loaded.currents["idd2n"], rel=1e-9)
    assert main(["calibrate", "--runs", str(tmp_path / "RUNS.json"), "--physical-rules"]) == 0
    assert "held at a physical rule (the data wants past it): background" in capsys.readouterr().out


def test_the_example_is_physical_and_physical_rules_write_a_memspec_that_loads(tmp_path, capsys) -> None:
    """examples/RUNS.json fits without an unphysical warning (its hidden truth is a physical device);
    with --physical-rules every rule of the memspec check holds — also IDD3N ≥ IDD3P, whose state no
    run uses — so the memspec written loads without --allow-unphysical (issue #28)."""
    from pathlib import Path

    from hdeem_watch.cli import main

    runs = Path(__file__).resolve().parents[2] / "examples" / "RUNS.json"
    assert main(["calibrate", "--runs", str(runs)]) == 0
    assert "unphysical" not in capsys.readouterr().err
    out = tmp_path / "physical.json"
    assert main(["calibrate", "--runs", str(runs), "--physical-rules", "--currents", "idd0,idd2n,idd3n",
                 "--write-memspec", str(out)]) == 0
    capsys.readouterr()
    spec = load_memspec(out)
    assert spec.currents["idd3n"] >= spec.currents["idd3p"] - 1e-12
    assert spec.currents["idd3n"] >= spec.currents["idd2n"] - 1e-12
