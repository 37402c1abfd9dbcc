"""The order tests/conftest.py gives the collected tests: the longest (``LONG_TESTS_FIRST``) first."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path
from types import ModuleType

import pytest

TESTS = Path(__file__).resolve().parent


def _conftest() -> ModuleType:
    spec = importlib.util.spec_from_file_location("hdeem_watch_tests_root_conftest", TESTS / "conftest.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


conftest = _conftest()


@pytest.mark.parametrize("prefix", conftest.LONG_TESTS_FIRST)
def test_each_long_test_entry_names_a_test_that_exists(prefix: str) -> None:
    """A stale entry (a renamed file or test) would silently order nothing."""
    path, _, name = prefix.partition("::")
    source = (TESTS.parent / path).read_text()
    assert not name or re.search(rf"^(async )?def {re.escape(name)}", source, re.M), prefix


def test_the_long_tests_come_first_and_the_rest_keep_their_order(request: pytest.FixtureRequest) -> None:
    """This session's tests come in the order of their entries, every other test after them."""
    ranks = [conftest.long_first_rank(item.nodeid) for item in request.session.items]
    assert ranks == sorted(ranks)
    assert conftest.long_first_rank("tests/demo/test_sim_runs.py::test_x") == 0
    assert conftest.long_first_rank("tests/test_cli.py::test_y") == len(conftest.LONG_TESTS_FIRST)
