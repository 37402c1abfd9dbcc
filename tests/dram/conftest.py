"""Fixtures of the DRAM tests: the DRAMPower v6.2 reference data (tests/data/drampower)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

#: <repo>/tests/data/drampower
DRAMPOWER_REF = Path(__file__).resolve().parents[1] / "data" / "drampower"

#: (results folder, memspec file) for every reference configuration.
REFERENCE_CONFIGS = {
    "1dev": "ddr4_2133_x8_2r_1dev.json",
    "allterms": "ddr4_2133_x8_2r_1dev_allterms.json",
}


def reference_cases() -> list[tuple[str, str]]:
    """Every (config, trace) pair that has a DRAMPower result file."""
    cases = []
    for config in sorted(REFERENCE_CONFIGS):
        for path in sorted((DRAMPOWER_REF / "results" / config).glob("*.cli.json")):
            cases.append((config, path.name.removesuffix(".cli.json")))
    return cases


@pytest.fixture(scope="session")
def drampower_ref() -> Path:
    """Folder of the DRAMPower reference data (skips nothing: it must exist)."""
    assert DRAMPOWER_REF.is_dir(), f"reference data missing at {DRAMPOWER_REF}"
    return DRAMPOWER_REF


def load_json(path: Path) -> Any:
    """Parse a JSON file."""
    return json.loads(path.read_text(encoding="utf-8"))


@pytest.fixture
def reference_memspec_json(drampower_ref: Path) -> dict[str, Any]:
    """The 1-device reference memspec as a parsed JSON tree (a fresh copy per test)."""
    return load_json(drampower_ref / "memspecs" / REFERENCE_CONFIGS["1dev"])


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    """Parametrize ``drampower_case`` with every (config, trace) reference case."""
    if "drampower_case" in metafunc.fixturenames:
        cases = reference_cases()
        metafunc.parametrize("drampower_case", cases, ids=[f"{c}-{t}" for c, t in cases])


@pytest.fixture
def reference_memspec_path(drampower_ref: Path):  # type: ignore[no-untyped-def]
    """Function: config name ("1dev", "allterms") -> path of its memspec file."""
    return lambda config: drampower_ref / "memspecs" / REFERENCE_CONFIGS[config]
