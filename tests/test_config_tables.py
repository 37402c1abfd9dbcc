"""The daemon's config file may hold tables that other commands read."""

from __future__ import annotations

from pathlib import Path

import pytest

from hdeem_watch.config import load_settings
from hdeem_watch.errors import InputError


def test_the_daemon_leaves_the_metricq_table_to_the_metricq_source(tmp_path: Path) -> None:
    """One file for the node: the daemon reads its keys and ignores [metricq] (it refused the file
    with "unknown setting 'metricq'" before); an unknown table is still an error."""
    config = tmp_path / "hdeem-watchd.toml"
    config.write_text('source = "sim"\nspeed = 2.0\n\n[metricq]\nserver = "amqp://broker/"\nprefix = "site"\n')
    settings = load_settings(config, env={})
    assert settings.source == "sim" and settings.speed == 2.0
    config.write_text('source = "sim"\n\n[metricq_typo]\nserver = "amqp://broker/"\n')
    with pytest.raises(InputError, match="metricq_typo"):
        load_settings(config, env={})
