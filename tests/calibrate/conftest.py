"""Fixtures of the calibrator's tests: synthetic rows (no energy model) and a truth generator."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

_HERE = Path(__file__).resolve().parent


def _load(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(f"calib_tests_{name}", _HERE / f"{name}.py")
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


SYNTH = _load("calib_synth")
REAL = _load("calib_real")

#: Hidden truth / datasheet ratios (in the range the seed paper reports for this kind of module).
TRUTH_RATIOS = SYNTH.TRUTH_RATIOS


@pytest.fixture
def synth() -> ModuleType:
    """The synthetic DDR4 column generator (tests/calibrate/calib_synth.py)."""
    return SYNTH


@pytest.fixture(scope="session")
def real() -> ModuleType:
    """Realistic runs from the real controller and energy models (tests/calibrate/calib_real.py)."""
    return REAL


@pytest.fixture
def truth_a() -> dict[str, float]:
    """Hidden true currents: the datasheet scaled by :data:`TRUTH_RATIOS`."""
    truth = dict(SYNTH.DATASHEET)
    for name, ratio in TRUTH_RATIOS.items():
        truth[name] *= ratio
    return truth


@pytest.fixture
def samsung():
    """The 8 GB DDR4-2133 RDIMM of the seed paper (one channel = one DIMM, 2 ranks × 9 devices)."""
    from hdeem_watch.dram.memspec import preset

    return preset("samsung-m393a1g43db0-cpb")


@pytest.fixture
def paper_truth(samsung) -> dict[str, float]:
    """Hidden per-device currents: the datasheet scaled by the seed paper's calibrated/datasheet
    ratios (IDD0 605/1120, IDD2N 599/1040, IDD3N 539/1540, IDD4R 967/1750, IDD4W 684/1590)."""
    ratios = {"idd0": 605 / 1120, "idd2n": 599 / 1040, "idd3n": 539 / 1540, "idd4r": 967 / 1750,
              "idd4w": 684 / 1590}
    return {name: samsung.currents[name] * ratio for name, ratio in ratios.items()}
