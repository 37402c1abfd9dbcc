"""The examples in the docstrings of the counter modules outside ``hdeem_watch.counters`` run and hold
(the daemon's counter windows and recording, the counter model; the TUI's rates; the perf_event
wrapper; the sim's are in ``tests/sim/test_doctests.py``)."""

from __future__ import annotations

import doctest
import importlib

import pytest

MODULES = ("hdeem_watch.daemon.counters.windows",
           "hdeem_watch.calibrate.counter_model", "hdeem_watch.daemon.counters.record",
           "hdeem_watch.tui.records",
           "hdeem_watch.tui.widgets.fmt", "hdeem_watch.perf_event")


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name: str) -> None:
    result = doctest.testmod(importlib.import_module(name))
    assert result.failed == 0 and (result.attempted > 0 or name == "hdeem_watch.perf_event")
