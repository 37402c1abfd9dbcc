"""The preset library (issue 15): every preset is physical, and ``hdeem-watch model kernel`` gives no
negative energy component for any preset and kernel."""

from __future__ import annotations

import json

import pytest

from hdeem_watch.cli import main
from hdeem_watch.dram.kernels import KERNELS
from hdeem_watch.dram.memspec import preset
from hdeem_watch.dram.memspec_check import physical_violations
from hdeem_watch.dram.presets import PRESET_INFO


@pytest.mark.parametrize("name", sorted(PRESET_INFO))
def test_model_kernel_energy_components_are_never_negative(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    """`model kernel --json` for every kernel on 4 channels: each component >= 0, activation and reads > 0."""
    for kernel in KERNELS:
        assert main(["model", "kernel", "--kernel", kernel, "--elements", str(1 << 16), "--threads", "4",
                     "--memspec", name, "--channels", "4", "--xor-bank", "--json"]) == 0
        energy = json.loads(capsys.readouterr().out)["energy"]
        assert all(value >= 0.0 for value in energy["components"].values()), (name, kernel, energy)
        assert energy["components"]["act_j"] > 0.0 and energy["components"]["rd_j"] > 0.0


@pytest.mark.parametrize("name", sorted(PRESET_INFO))
def test_every_preset_matches_what_it_says_it_is(name: str) -> None:
    """The JSON's width, die density and data rate are the ones the choice table uses; no violation."""
    info, spec = PRESET_INFO[name], preset(name)
    assert not physical_violations(spec)
    assert spec.width == info.width
    assert spec.nbr_of_banks * spec.nbr_of_rows * spec.nbr_of_columns * spec.width == info.die_gbit << 30
    assert abs(2 / float(spec.tck_s) / 1e6 - info.speed_mts) / info.speed_mts < 0.002
