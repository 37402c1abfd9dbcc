"""Calibrated currents on the DDR5 demo node against the sim's truth (issue #30's Done-when), one seed.

With the sim's Sapphire Rapids counters (both pseudo-channels, no per-rank CKE counter) every row
comes from the counted commands: IDD0/IDD4R/IDD4W come back determined and within 15 % of the
sim's truth incl. I/O, IDD2N (seen only in DDR5's mixed active standby, ρ = 0.5) is tied to IDD3N
and held, and the hold-out runs are predicted to a median within 5 % with the fit from before them
(the 4-thread pointer chase ~10 % high: it sits in active power-down, which no Sapphire Rapids
counter shows). Truth is the sim's own analytic mapping of its hidden currents
(``counted_currents_a``), never a fit. The node's currents are the DIMM mean of the two sockets'
own counted fits (RAPL measures each socket; the sockets are different parts): seed 2 is the one
where the single node fit over both sockets put IDD4R 16 % under the truth and IDD0 10 % over it;
``benchmarks/bench_trust.py --node ddr5`` has the figures over seeds."""

from __future__ import annotations

import statistics
from typing import Any

import pytest

from hdeem_watch.calibrate.trust import TrustOptions
from hdeem_watch.demo.nodes import DEMO_NODES
from hdeem_watch.demo.sim_runs import DEMO_TAIL_S, SimRuns

#: 160 sim runs of the DDR5 node refitted after each (~15 s of CPU): in the full run only.
pytestmark = [pytest.mark.xdist_group("demo-trust_ddr5"), pytest.mark.slow]

RUNS = 160


@pytest.fixture(scope="module")
def counted() -> tuple[SimRuns, list[Any]]:
    sim = SimRuns(2, counters=True, groups=False, holdout=True, tail_s=DEMO_TAIL_S,
                  node=DEMO_NODES["ddr5"])
    sim.modeller.set_trust(TrustOptions(jackknife=False, draws=0))
    done = [sim.step() for _ in range(RUNS)]
    sim.modeller.set_trust(TrustOptions())
    sim.modeller.refit()
    return sim, done


def test_idd0_idd4r_idd4w_are_determined_and_every_determined_current_is_within_15_percent(counted) -> None:
    sim, _done = counted
    fit_now = sim.modeller.latest_fit()
    truth = sim.sim.truth()["counted_currents_a"]
    assert fit_now["trust"]["commands"] == "counted"
    for name in ("idd0", "idd4r", "idd4w"):
        assert fit_now["currents"][name]["identifiable"], name
    for name, entry in fit_now["currents"].items():
        if entry["identifiable"]:
            assert entry["calibrated"] == pytest.approx(truth[name], rel=0.10), name
    assert set(fit_now["trust"]["per_socket"]) == {"DRAM0", "DRAM1"}


def test_idd2n_is_tied_to_idd3n_and_held(counted) -> None:
    sim, _done = counted
    fit_now = sim.modeller.latest_fit()
    held = fit_now["trust"]["held"]["idd2n"]
    assert held["tied"] is True and held["anchor"] == "idd3n"
    assert not fit_now["currents"]["idd2n"]["identifiable"]


def test_hold_out_runs_are_predicted_to_a_median_within_five_percent(counted) -> None:
    _sim, done = counted
    late = [d for d in done if (d.record.get("metadata") or {}).get("holdout") and d.index > 40]
    assert late
    errors = [abs(d.model["calibrated_j"] / d.record["dram_energy_j"] - 1) for d in late]
    assert statistics.median(errors) <= 0.05 and max(errors) <= 0.12, errors
    datasheet = [abs(d.model["datasheet_j"] / d.record["dram_energy_j"] - 1) for d in late]
    assert min(datasheet) > 0.5  # what the calibration is for


def test_calib_show_prints_both_sockets_values_of_the_counted_fits(counted) -> None:
    """`calib show` on this node lists each socket's own value under the node's (their DIMM mean)."""
    from hdeem_watch.cli.calib import format_fits

    sim, _done = counted
    fit_now = sim.modeller.latest_fit()
    lines = format_fits({"node": {"fit": fit_now}}, [], []).splitlines()
    start = next(i for i, line in enumerate(lines) if line.strip().startswith("per socket"))
    rows = {line.split()[0]: line.split()[1:] for line in lines[start + 1:start + 1 + len(fit_now["currents"])]}
    assert set(rows) == set(fit_now["currents"])
    for name, cells in rows.items():
        sockets = fit_now["trust"]["per_socket"]
        assert cells[0::2] == list(sockets)
        for sensor, cell in zip(sockets, cells[1::2], strict=True):
            entry = sockets[sensor][name]
            assert float(cell.rstrip("*")) == pytest.approx(entry["calibrated"] * 1e3, abs=0.006)
            assert cell.endswith("*") != entry["identifiable"]
