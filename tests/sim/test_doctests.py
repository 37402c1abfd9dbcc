"""The examples in the sim package's docstrings run and hold."""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import pytest

import hdeem_watch.sim as package

MODULES = sorted(m.name for m in pkgutil.iter_modules(package.__path__, prefix="hdeem_watch.sim."))


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name: str) -> None:
    """Every doctest of the module passes."""
    result = doctest.testmod(importlib.import_module(name))
    assert result.failed == 0
