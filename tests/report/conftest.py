"""Fixtures of the report tests: a real demo state unpacked into a temporary directory, a RUNS.json."""

from __future__ import annotations

import gzip
import shutil
from pathlib import Path

import pytest

DATA = Path(__file__).parent / "data"


@pytest.fixture
def state_dir(tmp_path: Path) -> Path:
    """A state directory holding the 60-second demo's ``state.db`` (see data/README.md)."""
    directory = tmp_path / "state"
    directory.mkdir()
    with gzip.open(DATA / "state-demo60.db.gz", "rb") as source, open(directory / "state.db", "wb") as target:
        shutil.copyfileobj(source, target)
    return directory


@pytest.fixture
def aged_state_dir(tmp_path: Path) -> Path:
    """A state directory holding a 150-second demo's ``state.db`` in which DDR_CD aged (per-pair
    fits, one drift alarm; see data/README.md)."""
    directory = tmp_path / "aged-state"
    directory.mkdir()
    with gzip.open(DATA / "state-demo150-aging.db.gz", "rb") as source, \
            open(directory / "state.db", "wb") as target:
        shutil.copyfileobj(source, target)
    return directory


@pytest.fixture
def runs_json() -> Path:
    """The RUNS.json made from that state (see data/README.md)."""
    return DATA / "runs.json"

