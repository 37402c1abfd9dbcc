"""The demo's runs on the real simulated node without sockets (demo/sim_runs.py): the done-when of
issue #16 on one seed each — an aging pair is named within 10 sim-minutes, a healthy node raises
nothing. The many-seed figures are ``benchmarks/bench_calibration.py``'s."""

from __future__ import annotations

import pytest

from hdeem_watch.demo.sim_runs import SimRuns


#: Long end-to-end accuracy checks (10-12 sim-minutes through the real calibrator: 10-20 s of CPU
#: each, nearly all of it the calibrator's own fits), so in the full run, not the quick one.
@pytest.mark.slow
def test_an_aging_pair_is_named_within_ten_sim_minutes() -> None:
    """``--sim-age DDR_CD=+30%/h`` (from sim time 0): the first alarm names DDR_CD, drifting up,
    before sim minute 10, and no other pair alarms."""
    runs = SimRuns(seed=1003, age={"DDR_CD": 0.30})
    alarms = [(done.t_s, a) for done in runs.until(600.0) for a in done.alarms]
    assert alarms, "no alarm in 10 sim-minutes"
    t_s, first = alarms[0]
    assert (first.group, first.kind, first.direction) == ("DDR_CD", "residual-cusum", "up") and t_s <= 600.0
    assert {a.group for _t, a in alarms} == {"DDR_CD"}, alarms


@pytest.mark.slow
def test_a_healthy_node_raises_no_alarm_and_its_runs_are_fitted() -> None:
    """Without aging, 12 sim-minutes of the demo (past the detectors' warm-up) raise no alarm; every
    run is long enough to be fitted (the schedule's shortest run is 1.25 s: 100 samples at 100 Sa/s
    with room to spare)."""
    runs = SimRuns(seed=1004)
    done = list(runs.until(720.0))
    assert [a for d in done for a in d.alarms] == []
    assert [d.error for d in done if d.error is not None] == []
    calib = runs.modeller.group_fits.calibrators
    assert calib.detectors["DDR_AB"].scale == calib.detectors["DDR_AB"].scale  # learnt (not NaN)
