"""The ``counters`` setting (issue 17): its values, what each needs, and the one-line errors."""

from __future__ import annotations

import pytest

from hdeem_watch.config import DaemonSettings, SettingError, load_settings


def test_counters_default_off_and_validated(tmp_path) -> None:
    assert DaemonSettings(state_dir=str(tmp_path)).counters == "none"
    assert DaemonSettings(state_dir=str(tmp_path), counters="sim").counters == "sim"
    with pytest.raises(SettingError, match=r"counters = 'pmu'; expected one of none, sim, perf, replay"):
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


@pytest.mark.slow
def test_perf_counters_on_this_vm_are_refused_with_the_reason(daemon_factory) -> None:
    """No uncore_imc PMU in a VM: the daemon says so in one line and exits 2."""
    daemon = daemon_factory("--counters", "perf", name="perf")
    with pytest.raises(RuntimeError, match=r"exited with 2: .*counters perf: .*(uncore_imc|IMC event table)"):
        daemon.start(timeout_s=30)
