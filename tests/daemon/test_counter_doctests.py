"""The examples in the docstrings of the counter modules outside ``hdeem_watch.counters`` run and hold
(the daemon's counter source, windows, model and recording; the sim's jobs and hidden commands; the
TUI's rates; the perf_event wrapper)."""

from __future__ import annotations

import doctest
import importlib

import pytest

MODULES = ("hdeem_watch.daemon.counter_source", "hdeem_watch.daemon.counters.windows",
           "hdeem_watch.calibrate.counter_model", "hdeem_watch.daemon.counters.record",
           "hdeem_watch.sources.sim_jobs", "hdeem_watch.sources.sim_commands", "hdeem_watch.tui.records",
           "hdeem_watch.tui.widgets.fmt", "hdeem_watch.perf_event")


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name: str) -> None:
    result = doctest.testmod(importlib.import_module(name))
    assert result.failed == 0 and (result.attempted > 0 or name == "hdeem_watch.perf_event")
