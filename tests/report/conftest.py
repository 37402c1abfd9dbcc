"""Fixtures of the report tests: a real demo state unpacked into a temporary directory, a RUNS.json."""

from __future__ import annotations

import gzip
import shutil
from pathlib import Path

import pytest

DATA = Path(__file__).parent / "data"


def unpack_demo_state(directory: Path) -> Path:
    """``directory`` made to hold the 60-second demo's ``state.db`` (see data/README.md)."""
    directory.mkdir()
    with gzip.open(DATA / "state-demo60.db.gz", "rb") as source, open(directory / "state.db", "wb") as target:
        shutil.copyfileobj(source, target)
    return directory


@pytest.fixture
def state_dir(tmp_path: Path) -> Path:
    """A state directory holding the 60-second demo's ``state.db``, the test's own to change."""
    return unpack_demo_state(tmp_path / "state")


@pytest.fixture(scope="module")
def shared_state_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The same state directory, once per module, for tests that only read it."""
    return unpack_demo_state(tmp_path_factory.mktemp("shared") / "state")


@pytest.fixture
def fresh_state_dir(tmp_path: Path) -> Path:
    """The state directory of a daemon that has just started: no runs, no fits, no baselines."""
    from hdeem_watch.daemon.store.database import Store

    directory = tmp_path / "fresh-state"
    Store(directory / "state.db").close()
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

