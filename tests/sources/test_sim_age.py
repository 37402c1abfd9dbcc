"""Aging of one DIMM pair in sim time (issue 16): the ``--sim-age`` parser and the drift it puts on the node."""

from __future__ import annotations

import numpy as np
import pytest

from hdeem_watch.errors import InputError
from hdeem_watch.sim.age import age_factor, check_pairs, parse_sim_age, parse_sim_age_start
from hdeem_watch.sources.sim import SimSource

S = 1_000_000_000
PAIRS = ("DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH")


@pytest.mark.parametrize(("text", "rates"), [
    ("DDR_CD=+30%/h", {"DDR_CD": 0.30}),
    ("ddr_cd=30%/h", {"DDR_CD": 0.30}),
    ("DDR_AB=+0.5%/min, DDR_GH=-10%/h", {"DDR_AB": 0.30, "DDR_GH": -0.10}),
    ("DDR_EF=+1%/s@10min", {"DDR_EF": 36.0}),
])
def test_parse_sim_age_forms(text: str, rates: dict[str, float]) -> None:
    """PAIR=±X%/h (or /min, /s) gives the relative growth per sim hour, pair names upper-cased."""
    parsed = parse_sim_age(text)
    assert parsed.keys() == rates.keys()
    for pair, rate in rates.items():
        assert parsed[pair] == pytest.approx(rate, rel=1e-12)


def test_parse_sim_age_start() -> None:
    """An optional @<start> (s, min or h) delays the drift; without it the drift starts at the open."""
    assert parse_sim_age_start("DDR_CD=+30%/h@600s,DDR_AB=+5%/h") == {"DDR_CD": 600.0, "DDR_AB": 0.0}
    assert parse_sim_age_start("DDR_CD=+30%/h@0.5h") == {"DDR_CD": 1800.0}


@pytest.mark.parametrize("text", ["", "DDR_CD", "DDR_CD=+30", "DDR_CD=+30%", "DDR_CD=30%/day", "=+30%/h",
                                  "DDR_CD=+30%/h,DDR_CD=+5%/h", "DDR_CD=abc%/h"])
def test_parse_sim_age_rejects_bad_forms(text: str) -> None:
    """Bad input is one InputError line naming the item and the expected form."""
    with pytest.raises(InputError) as error:
        parse_sim_age(text)
    message = str(error.value)
    assert "\n" not in message
    assert "PAIR=" in message or "twice" in message


def test_unknown_pair_is_rejected() -> None:
    """A pair the node does not have is an InputError naming it and the node's pairs."""
    with pytest.raises(InputError, match=r"DDR_ZZ.*DDR_AB, DDR_CD"):
        check_pairs({"DDR_ZZ": 0.3}, PAIRS)
    with pytest.raises(InputError, match="DDR_XY"):
        SimSource(seed=1, age={"DDR_XY": 0.3})
    with pytest.raises(InputError, match="finite"):
        check_pairs({"DDR_AB": float("nan")}, PAIRS)


def test_age_factor_is_linear_from_the_start() -> None:
    """The factor is 1 before the start and grows linearly with sim hours after it."""
    assert age_factor(0.3, 600.0, 300.0) == 1.0
    assert age_factor(0.3, 600.0, 600.0 + 3600.0) == pytest.approx(1.3)
    assert age_factor(-2.0, 0.0, 7200.0) == 0.05   # never a negative current


def test_aging_drifts_the_named_pair_only(fake_clock) -> None:
    """+30 %/h on DDR_CD: after one sim hour DDR_CD's true currents are 1.3×, every other pair's unchanged,
    and the sensors show it (DDR_CD's idle reading up, the others flat)."""
    clock = fake_clock()
    sim = SimSource(seed=3, clock=clock, wall_clock=lambda: 0, speed=60.0, age={"DDR_CD": 0.30}, temp_amp_c=0.0,
                    noise=False, quantum_w=0.0)
    sim.open()
    clock.t = S // 10
    first = sim.poll()
    before = sim.truth()
    clock.t = 60 * S + S // 10   # one sim hour later at speed 60
    sim.poll()
    clock.t += S // 10
    last = sim.poll()
    after = sim.truth()
    for pair in PAIRS:
        ratio = np.array([after["pairs"][pair]["currents_a"][n] / v
                          for n, v in before["pairs"][pair]["currents_a"].items() if v > 0])
        expected = 1.3 if pair == "DDR_CD" else 1.0
        assert np.allclose(ratio, expected, rtol=1e-3), (pair, ratio)
        reading = float(last.samples[pair][1].mean()) / float(first.samples[pair][1].mean())
        if pair == "DDR_CD":
            assert reading > 1.15
        else:
            assert reading == pytest.approx(1.0, abs=1e-6)
    assert after["aging"] == {"DDR_CD": {"rate_per_h": 0.30, "start_s": 0.0,
                                         "factor": pytest.approx(1.3, rel=1e-3)}}
    assert after["pairs"]["DDR_CD"]["age_factor"] == pytest.approx(1.3, rel=1e-3)
    assert after["pairs"]["DDR_AB"]["age_factor"] == 1.0
    assert after["physical_violations"] == {}


def test_aging_starts_when_told(fake_clock) -> None:
    """With a start at 30 sim-minutes, the pair is unchanged before it and drifts after it."""
    clock = fake_clock()
    sim = SimSource(seed=3, clock=clock, wall_clock=lambda: 0, speed=60.0, age={"DDR_GH": 0.30},
                    age_start_s={"DDR_GH": 1800.0}, temp_amp_c=0.0)
    sim.open()
    idd0 = []
    for minutes in (0, 29, 60):
        clock.t = minutes * S
        sim.poll()
        idd0.append(sim.truth()["pairs"]["DDR_GH"]["currents_a"]["idd0"])
    assert idd0[1] == pytest.approx(idd0[0], rel=1e-12)
    assert idd0[2] == pytest.approx(idd0[0] * 1.15, rel=1e-3)


def test_sim_age_options_build_an_aging_sim() -> None:
    """The options of a --sim-age value go straight into SimSource; none for an unset value."""
    from hdeem_watch.sim.age import sim_age_options

    assert sim_age_options(None) == {} and sim_age_options("  ") == {}
    sim = SimSource(seed=1, **sim_age_options("DDR_CD=+30%/h@10min"))
    assert sim.truth()["aging"] == {"DDR_CD": {"rate_per_h": 0.3, "start_s": 600.0, "factor": 1.0}}
