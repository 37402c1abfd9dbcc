"""The fixture trees the tests share from pytest's cache are exactly what their generators build.

The trees are built once per generator source and kept between runs (``tests/conftest.py``), so
a test that wrote into one would change it for every later run. This check builds each afresh and
compares every entry: its kind, its bytes, its mode and its link target.
"""

from __future__ import annotations

import os
import stat
from collections.abc import Callable
from pathlib import Path

import pytest


def _entries(root: Path) -> dict[str, tuple[str, bytes | str, int]]:
    """Every path under ``root`` → (kind, content or link target, permission bits)."""
    entries: dict[str, tuple[str, bytes | str, int]] = {}
    for path in sorted(root.rglob("*")):
        info = path.lstat()
        key = str(path.relative_to(root))
        if stat.S_ISLNK(info.st_mode):
            entries[key] = ("link", os.readlink(path), 0)
        elif stat.S_ISDIR(info.st_mode):
            entries[key] = ("dir", b"", stat.S_IMODE(info.st_mode))
        else:
            entries[key] = ("file", path.read_bytes(), stat.S_IMODE(info.st_mode))
    return entries


@pytest.mark.slow
@pytest.mark.parametrize(("fixture", "generator"), [("node_trees", "node/make_fixtures.py"),
                                                     ("pmu_trees", "counters/pmu_trees.py"),
                                                     ("powercap_trees", "sources/powercap_trees.py")])
def test_the_shared_trees_are_what_their_generator_builds(fixture: str, generator: str, tmp_path: Path,
                                                          build_trees: Callable[[str, Path], Path],
                                                          request: pytest.FixtureRequest) -> None:
    shared = request.getfixturevalue(fixture)
    fresh = build_trees(generator, tmp_path / "fresh")
    want, got = _entries(fresh), _entries(shared)
    assert sorted(got) == sorted(want)
    changed = [key for key in want if got[key] != want[key]]
    assert not changed, f"changed since they were built: {changed[:5]}"
