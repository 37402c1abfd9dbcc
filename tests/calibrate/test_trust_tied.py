"""The held-current rule for a standby current the rows only ever see mixed with its anchor (DDR5).

DRAMPower's DDR5 memspec books active standby as ``ρ·IDD3N + (1 − ρ)·IDD2N`` (its test memspec:
ρ = 0.5), and a counted window of a busy rank is almost all active standby: IDD2N and IDD3N then
appear in every row in one fixed mix, so neither is determined, and the old rule (hold IDD2N only
when its anchor IDD3N is determined) held nothing. The tied rule folds IDD2N into IDD3N at their
datasheet ratio, holds it there, and carries the range of IDD2N the rows do not reject into the
other currents' intervals. Judged against the truth that made the rows."""

from __future__ import annotations

import numpy as np
import pytest

from hdeem_watch.calibrate.fit import FitOptions
from hdeem_watch.calibrate.observation import Observation
from hdeem_watch.calibrate.trust import TrustOptions, trusted_fit

NAMES = ("idd0", "idd2n", "idd3n", "idd4r", "idd2p")
DATASHEET = {"idd0": 0.05625, "idd2n": 0.03375, "idd3n": 0.0395, "idd4r": 0.1575, "idd2p": 0.017}
TRUTH = np.array([0.0221, 0.0090, 0.0118, 0.0994, 0.0021])


class Spec:
    currents = DATASHEET


def _rows(seed: int = 4, runs: int = 120, noise: float = 0.015) -> list[Observation]:
    """Busy windows (active standby = 0.48·IDD2N + 0.52·IDD3N, the ACT energy with its −IDD2N·(tRC −
    tRAS) share, a little precharged standby in half the kinds, bursts) and idle ones (precharge
    power-down), 30 kinds, 1.5 % noise by default (above the fit's
    1 % noise floor, so the F test decides the range)."""
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(runs):
        kind = i % 30
        if kind == 0:
            columns = np.array([0.0, 0.0, 0.0, 0.0, rng.uniform(60, 120)])
        else:
            standby, acts, bursts = rng.uniform(40, 80), rng.uniform(1, 30) * (1 + kind % 3), rng.uniform(5, 40)
            precharged = 0.2 * (kind % 2)  # a little precharged standby in some windows: not exactly collinear
            columns = np.array([acts, 0.48 * standby - 0.4 * acts + precharged, 0.52 * standby, bursts,
                                rng.uniform(0, 3)])
        measured = float(columns @ TRUTH) * (1 + noise * rng.normal())
        rows.append(Observation(f"r{i}:k{kind}", columns, 0.0, measured))
    return rows


@pytest.fixture(scope="module")
def tied():
    options = FitOptions(currents=NAMES, names=NAMES, intercept=False)
    return trusted_fit(_rows(), Spec(), options, trust=TrustOptions())


def test_idd2n_is_tied_to_idd3n_at_the_datasheet_ratio_and_not_called_determined(tied) -> None:
    held = tied.trust["held"]["idd2n"]
    value = dict(zip(tied.currents, tied.calibrated_a))
    assert held["anchor"] == "idd3n" and held["tied"] is True
    assert value["idd2n"] == pytest.approx(value["idd3n"] * DATASHEET["idd2n"] / DATASHEET["idd3n"], rel=1e-3)
    mix = 0.48 * value["idd2n"] + 0.52 * value["idd3n"]  # what the rows see
    assert mix == pytest.approx(0.48 * TRUTH[1] + 0.52 * TRUTH[2], rel=0.05)
    j = tied.currents.index("idd2n")
    assert not tied.identifiable[j]
    low, high = held["range"]
    assert low <= TRUTH[1] <= high and tuple(tied.ci95_a[j]) == pytest.approx((low, high))


def test_the_currents_the_rows_separate_are_determined_and_their_intervals_cover_the_truth(tied) -> None:
    for j, name in enumerate(tied.currents):
        low, high = tied.ci95_a[j]
        assert low <= TRUTH[j] <= high, name
        if name in ("idd0", "idd4r"):
            assert tied.identifiable[j], name
            assert tied.calibrated_a[j] == pytest.approx(TRUTH[j], rel=0.05), name
    assert not tied.identifiable[tied.currents.index("idd3n")]  # its split from IDD2N is not in the rows


def test_the_range_is_what_the_rows_do_not_reject_not_the_whole_physical_span(tied) -> None:
    """IDD2P ≤ IDD2N ≤ IDD3N is the physical span; the F test keeps the part the rows accept, so
    IDD0 (which trades with IDD2N through the activation energy) stays determined."""
    low, high = tied.trust["held"]["idd2n"]["range"]
    value = dict(zip(tied.currents, tied.calibrated_a))
    assert low >= value["idd2p"] and high <= value["idd3n"] * (1 + 1e-9)
    assert high - low < value["idd3n"] - value["idd2p"]


def test_exact_rows_do_not_shrink_the_range_to_a_point() -> None:
    """Rows without noise fit exactly at every IDD2N of the flat valley: the F test's best is taken at
    no less than the fit's 1 % noise floor, so the range keeps the valley (and the truth)."""
    options = FitOptions(currents=NAMES, names=NAMES, intercept=False)
    exact = trusted_fit(_rows(noise=0.0), Spec(), options, trust=TrustOptions())
    low, high = exact.trust["held"]["idd2n"]["range"]
    assert low <= TRUTH[1] <= high and high - low > 0.2 * TRUTH[1]
