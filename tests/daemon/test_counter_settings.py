"""The ``counters`` setting (issue 17): its values, what each needs, and the one-line errors."""

from __future__ import annotations

import logging
from types import SimpleNamespace

import pytest

from hdeem_watch.config import DaemonSettings, SettingError, load_settings
from hdeem_watch.counters.source import auto_counter_kind
from hdeem_watch.daemon.counters.feed import CounterFeed
from hdeem_watch.errors import InputError
from hdeem_watch.sim.model import MEMSPEC_PRESET


def test_counters_default_auto_and_validated(tmp_path) -> None:
    assert DaemonSettings(state_dir=str(tmp_path)).counters == "auto"
    assert DaemonSettings(state_dir=str(tmp_path), source="rapl").counters == "auto"
    assert DaemonSettings(state_dir=str(tmp_path), counters="sim").counters == "sim"
    with pytest.raises(SettingError, match=r"counters = 'pmu'; expected one of auto, none, sim, perf, replay"):
        DaemonSettings(state_dir=str(tmp_path), counters="pmu")
    with pytest.raises(SettingError, match="needs source = 'sim'"):
        DaemonSettings(state_dir=str(tmp_path), source="rapl", counters="sim")
    with pytest.raises(SettingError, match="needs source = 'replay'"):
        DaemonSettings(state_dir=str(tmp_path), counters="replay")


def test_counters_from_file_and_environment(tmp_path) -> None:
    config = tmp_path / "d.toml"
    config.write_text('counters = "sim"\n')
    assert load_settings(config, env={}).counters == "sim"
    assert load_settings(None, env={"HDEEM_WATCH_COUNTERS": "perf"}).counters == "perf"


@pytest.mark.parametrize(("source", "recorded", "kind"), [
    ("sim", False, "sim"), ("hdeem", False, "perf"), ("rapl", False, "perf"),
    ("replay", True, "replay"), ("replay", False, "none")])
def test_auto_tries_the_sources_own_counters(source, recorded, kind) -> None:
    assert auto_counter_kind(source, replay_has_counters=recorded) == kind


def test_auto_on_a_node_without_imc_pmus_falls_back_to_the_model_and_says_so(tmp_path, caplog) -> None:
    """A real source whose host has no ``uncore_imc`` PMU (this VM: perf's plan refuses it):
    ``auto`` opens nothing, raises nothing, and logs once why and which commands the fits use."""
    caplog.set_level(logging.INFO, logger="hdeem_watch.daemon")
    book = SimpleNamespace(sample_time_of=lambda t: t)
    feed = CounterFeed.open("auto", object(), book, memspec=MEMSPEC_PRESET, clock=lambda: 0,  # type: ignore[arg-type]
                            heartbeat_s=1.0, record_file=None, replay_file=None, source_kind="hdeem")
    assert feed is None
    with pytest.raises(InputError, match="unknown memspec preset"):  # a wrong memspec is not a missing PMU
        CounterFeed.open("auto", object(), book, memspec="MT40A1G8SA-075E", clock=lambda: 0,  # type: ignore[arg-type]
                         heartbeat_s=1.0, record_file=None, replay_file=None, source_kind="hdeem")
    lines = [r.getMessage() for r in caplog.records if r.getMessage().startswith("counters:")]
    assert len(lines) == 1
    assert "counters: none (auto: counters perf:" in lines[0] and "kernel model's commands" in lines[0]
    with pytest.raises(InputError, match="counters perf:"):  # asked for explicitly, the same host refuses
        CounterFeed.open("perf", object(), book, memspec=MEMSPEC_PRESET, clock=lambda: 0,  # type: ignore[arg-type]
                         heartbeat_s=1.0, record_file=None, replay_file=None)


@pytest.mark.slow
def test_perf_counters_on_this_vm_are_refused_with_the_reason(daemon_factory) -> None:
    """No uncore_imc PMU in a VM: the daemon says so in one line and exits 2."""
    daemon = daemon_factory("--counters", "perf", name="perf")
    with pytest.raises(RuntimeError, match=r"exited with 2: .*counters perf: .*(uncore_imc|IMC event table)"):
        daemon.start(timeout_s=30)
