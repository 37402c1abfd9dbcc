"""A client's mistake is the client's: answered ``bad-args``, logged below ERROR, its value cut.

``calib.reset`` of an unknown group once failed on the model worker and was logged at ERROR as a
failed model job with the whole value (up to 64 KB in one log line).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from hdeem_watch.config import DaemonSettings
from hdeem_watch.daemon.shell.service import Daemon
from hdeem_watch.sources.sim import SimSource
from hdeem_watch.wire.client import ControlClient, ControlError


@pytest.fixture
def control(tmp_path: Path) -> Iterator[str]:
    """A sim daemon in this process (its log records reach caplog); its control endpoint."""
    settings = DaemonSettings(pub=f"ipc://{tmp_path}/p.sock", control=f"ipc://{tmp_path}/c.sock",
                              state_dir=str(tmp_path / "s"), node="n", speed=20.0, heartbeat_s=0.2)
    daemon = Daemon(settings, source=SimSource(seed=3, speed=20.0))
    daemon.start()
    loop = threading.Thread(target=daemon.run)
    loop.start()
    try:
        yield daemon.control_endpoint
    finally:
        daemon.request_stop()
        loop.join()
        daemon.close()


@pytest.mark.slow
@pytest.mark.parametrize("group", ["DDR_XY", "x" * 60_000, "y" * 65], ids=["unknown", "60k", "65-chars"])
def test_calib_reset_of_an_unknown_group_is_a_client_error_not_a_failed_job(
        control: str, group: str, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG)
    with ControlClient(control, timeout_s=20.0) as client:
        client.call("status")  # the model worker has built its modeller
        with pytest.raises(ControlError) as refused:
            client.call("calib.reset", {"group": group})
        assert client.call("ping")["pong"] is True
    assert refused.value.code == "bad-args" and group[:6] in refused.value.message
    assert len(refused.value.message) < 400
    assert [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR] == []
    assert all(len(r.getMessage()) < 600 for r in caplog.records)


@pytest.mark.slow
def test_a_huge_job_id_is_refused_in_one_short_line(control: str) -> None:
    with ControlClient(control, timeout_s=5.0) as client, pytest.raises(ControlError) as refused:
        client.call("job.start", {"job_id": "7" * 60_000})
    assert refused.value.code == "bad-args" and len(refused.value.message) < 400
