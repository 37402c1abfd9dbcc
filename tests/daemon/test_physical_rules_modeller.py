"""The daemon's ``physical_rules`` setting: the node fit and every per-pair fit keep the ordering
rules between calibrated currents, also over a calibrator restored from a state saved without it."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hdeem_watch.calibrate.group_fits import default_groups
from hdeem_watch.calibrate.group_rows import group_observation
from hdeem_watch.calibrate.observation import current_names
from hdeem_watch.calibrate.run_model import RunModeller
from hdeem_watch.config import load_settings
from hdeem_watch.dram.memspec_check import physical_violations
from hdeem_watch.errors import InputError
from hdeem_watch.run_record import RunRecord

MEMSPEC = "samsung-m393a1g43db0-cpb"
RATES = {"DDR_AB": 100.0, "DDR_CD": 100.0, "DDR_EF": 100.0, "DDR_GH": 100.0}
GROUPS = default_groups(RATES, 2, 4)
#: The seed paper's calibrated/datasheet ratios: its own calibration has IDD3N below IDD2N.
PAPER = {"idd0": 605 / 1120, "idd2n": 599 / 1040, "idd3n": 539 / 1540, "idd4r": 967 / 1750, "idd4w": 684 / 1590}
SCHEDULE = [("idle", 1), ("read", 4), ("triad", 24), ("copy", 12), ("read", 24), ("assign", 6), ("idle", 1),
            ("add", 18), ("scale", 8), ("triad", 6), ("copy", 24), ("read", 12), ("idle", 1), ("add", 4)]


def _record(m: RunModeller, i: int, kernel: str, threads: int) -> dict[str, Any]:
    """A run whose pairs draw the paper's currents (energies from the model's own rows); windows of
    3–7 s, so the background is not a constant per run (which the intercept would take)."""
    window_s = 3.0 + i % 5
    record: dict[str, Any] = {"run_id": f"r{i}", "name": kernel, "kernel": kernel, "threads": threads,
                              "elements": 0 if kernel == "idle" else 1 << 22, "repeat": 4, "window_s": window_s,
                              "t_stop_ns": (i + 1) * 10**9}
    stats = m.groups_for(kernel, record["elements"], threads, record["repeat"])
    truth = m.spec.with_currents({n: m.spec.currents[n] * r for n, r in PAPER.items()})
    vec = np.array([float(truth.currents.get(n, 0.0)) for n in current_names()])
    record["energy_j"] = {g.name: group_observation(m.spec, stats, g, window_s, 1.0).predicted_j(vec) for g in GROUPS}
    record["dram_energy_j"] = sum(record["energy_j"].values())
    return RunRecord.from_dict({"state": "modelling", **record})


def _modeller(**kwargs: Any) -> RunModeller:
    return RunModeller(MEMSPEC, max_requests=100_000, groups=GROUPS, dram_rates_hz=RATES, **kwargs)


def _run(m: RunModeller, schedule: list[tuple[str, int]], start: int = 0) -> None:
    for i, (kernel, threads) in enumerate(schedule, start):
        _model, fit, error = m.evaluate(_record(m, i, kernel, threads))
        assert error is None and fit is not None


def _broken(m: RunModeller, fit: dict[str, Any]) -> list[str]:
    return physical_violations(m.spec.with_currents({n: c["calibrated"] for n, c in fit["currents"].items()}))


def test_the_setting_keeps_node_and_pair_fits_physical() -> None:
    """Without the setting the node fit finds the paper's IDD3N < IDD2N; with it, the node fit and
    each pair's fit hold IDD3N = IDD2N and say so."""
    measured, physical = _modeller(), _modeller(physical_rules=True)
    _run(measured, SCHEDULE)
    _run(physical, SCHEDULE)
    assert any(v.startswith("background") for v in _broken(measured, measured.body()["fit"]))
    body = physical.body()
    assert _broken(physical, body["fit"]) == [] and "background" in body["fit"]["rules_held"]
    assert physical.group_fits is not None and physical.group_fits.calibrators is not None
    for name, calibrator in physical.group_fits.calibrators.calibrators.items():
        assert calibrator.latest is not None, name
        assert "background" in calibrator.latest.rules_held, name


def test_the_setting_applies_over_a_restored_calibrator() -> None:
    """A state saved without the setting, restored with it: the next refit keeps the rules."""
    before = _modeller()
    _run(before, SCHEDULE[:8])
    state = json.loads(json.dumps(before.state()))
    assert state["settings"]["rules"] is False
    after = _modeller(physical_rules=True, state=state)
    assert after.restore_error is None and after.calibrator.rules
    _run(after, SCHEDULE[8:], start=8)
    assert _broken(after, after.body()["fit"]) == []
    assert after.state()["settings"]["rules"] is True


def test_the_setting_is_read_from_the_config_file(tmp_path: Path) -> None:
    config = tmp_path / "hdeem-watch.toml"
    config.write_text("[daemon]\nphysical_rules = true\n")
    assert load_settings(config, env={}).physical_rules is True
    assert load_settings(None, env={}).physical_rules is False
    config.write_text("[daemon]\nphysical_rules = 3\n")
    with pytest.raises(InputError, match="physical_rules"):
        load_settings(config, env={})
