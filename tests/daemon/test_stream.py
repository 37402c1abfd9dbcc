"""The daemon as a real process: sample stream rates, gaps, energy accounting, heartbeat, late joiners."""

from __future__ import annotations

import math
from collections import defaultdict
from typing import Any

import numpy as np
import pytest

from hdeem_watch.config import DaemonSettings
from hdeem_watch.sources.base import hdeem_channel_infos
from hdeem_watch.wire import protocol

# One worker runs the module, so its module-scoped fixture is built once, not once per worker.
pytestmark = pytest.mark.xdist_group("daemon-stream")

NOMINAL = {info.name: info.rate_hz for info in hdeem_channel_infos()}


def _by_channel(messages: list[protocol.Message]) -> dict[str, list[protocol.Message]]:
    out: dict[str, list[protocol.Message]] = defaultdict(list)
    for m in messages:
        if m.kind == "samples":
            out[m.channel or ""].append(m)
    return out


@pytest.fixture(scope="module")
def sample_stream(shared_daemon: Any, receive: Any) -> list[protocol.Message]:
    """2.5 s of the shared daemon's sample stream, every channel (read once, checked by several tests)."""
    sub = shared_daemon.subscriber(protocol.subscription(shared_daemon.node, "samples"))
    messages: list[protocol.Message] = receive(sub, 2.5)
    sub.close()
    return messages


@pytest.mark.slow
def test_every_channel_at_its_native_rate_without_gaps(sample_stream: list[protocol.Message]) -> None:
    """Each HDEEM channel arrives at its native rate (sample time), consecutive seq, no missing sample."""
    channels = _by_channel(sample_stream)
    assert set(channels) == set(NOMINAL)
    for name, batches in channels.items():
        seqs = [m.seq for m in batches]
        assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), f"{name}: sequence gap"
        t = np.concatenate([m.samples()[0] for m in batches])
        period = round(1e9 / NOMINAL[name])
        steps = np.diff(t)
        assert np.all(steps == period), f"{name}: irregular or missing samples {np.unique(steps)[:5]}"
        rate = (len(t) - 1) / ((t[-1] - t[0]) / 1e9)
        assert abs(rate - NOMINAL[name]) / NOMINAL[name] < 1e-6
        assert all(m.header["rate_hz"] == NOMINAL[name] and m.header["unit"] == "W" for m in batches)
        # At speed 10 the sim produces 10 × the native rate per wall second: the daemon keeps up.
        assert len(t) > 0.5 * 10 * NOMINAL[name] * 2.0


@pytest.mark.slow
def test_stream_energy_is_the_sum_of_the_samples(sample_stream: list[protocol.Message]) -> None:
    """The cumulative energy_j in the headers (the source's own totals) grows by exactly Σ power × period."""
    for name, batches in _by_channel(sample_stream).items():
        period_s = 1.0 / NOMINAL[name]
        integrated = sum(float(m.samples()[1].sum()) * period_s for m in batches[1:])
        booked = batches[-1].header["energy_j"] - batches[0].header["energy_j"]
        assert booked > 0
        assert math.isclose(integrated, booked, rel_tol=1e-9, abs_tol=1e-9), name


@pytest.mark.slow
def test_heartbeat_reports_rates_health_and_process(shared_daemon: Any, receive: Any) -> None:
    """A status heartbeat arrives every second with measured rates, no gaps, source health, CPU and RSS."""
    sub = shared_daemon.subscriber(protocol.subscription(shared_daemon.node, "status"))
    beats = receive(sub, 3.5, until=lambda ms: len(ms) >= 3)
    sub.close()
    assert len(beats) >= 3
    seqs = [b.seq for b in beats]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))
    gaps_s = np.diff([b.t_ns for b in beats]) / 1e9
    assert np.all(np.abs(gaps_s - 1.0) < 0.3)
    last = beats[-1].header
    assert last["source"] == {"kind": "sim", "health": "ok"}
    assert last["process"]["rss_bytes"] > 10_000_000
    assert 0 <= last["process"]["cpu_percent"] < 100
    assert last["uptime_s"] > 0 and last["speed"] == 10.0
    for name, entry in last["channels"].items():
        assert entry["gaps"] == 0 and entry["status"] == "ok"
        assert abs(entry["rate_hz"] - NOMINAL[name]) / NOMINAL[name] < 0.01
        assert entry["nominal_hz"] == NOMINAL[name]
        assert entry["energy_j"] > 0 and entry["power_w"] >= 0


@pytest.mark.slow
def test_late_joiner_gets_calibration_and_baselines_at_once(shared_daemon: Any, receive: Any) -> None:
    """A subscriber that connects late receives calib and baseline within a fraction of the re-publish period."""
    sub = shared_daemon.subscriber(protocol.subscription(shared_daemon.node))
    got = receive(sub, 3.0, until=lambda ms: {"calib", "baseline"} <= {m.kind for m in ms})
    sub.close()
    kinds = {m.kind for m in got}
    assert {"calib", "baseline"} <= kinds
    calib = next(m for m in got if m.kind == "calib").header
    assert {"fit", "history", "runs", "truth"} <= set(calib)
    assert calib["truth"]["simulated"] is True
    assert "channels" in next(m for m in got if m.kind == "baseline").header


@pytest.mark.slow
def test_status_op_names_node_endpoints_source_and_channels(shared_daemon: Any, receive: Any) -> None:
    """The status op answers with node, endpoints, source and every channel."""
    with shared_daemon.client() as client:
        status = client.call("status")
    assert status["node"] == shared_daemon.node
    assert status["endpoints"] == {"pub": shared_daemon.pub, "control": shared_daemon.control,
                                   "remote": {"pub": None, "control": None}}  # ipc: nothing for other nodes
    assert status["source"]["kind"] == "sim"
    assert set(status["channels"]) == set(NOMINAL)


@pytest.mark.slow
def test_quiet_periods_become_baselines(shared_daemon: Any) -> None:
    """An idle node yields a quiet-period baseline per DRAM channel: mean, small spread, enough samples."""
    import time

    deadline = time.monotonic() + 10.0
    with shared_daemon.client() as client:
        while True:
            channels = client.call("baseline.get")["channels"]
            dram = {k: v for k, v in channels.items() if k.startswith("DDR_")}
            if len(dram) == 4 or time.monotonic() > deadline:
                break
            time.sleep(0.2)
        status = client.call("status")
    assert len(dram) == 4, channels
    for name, entry in dram.items():
        assert entry["origin"] in ("quiet", "idle-run")
        if entry["origin"] == "quiet":
            assert entry["n"] == 200  # 2 s at 100 Sa/s
            assert 0 <= entry["spread_w"] <= max(0.5, 0.05 * entry["power_w"])
        assert abs(entry["power_w"] - status["channels"][name]["power_w"]) < 2.0


@pytest.mark.slow
def test_polls_slowly_while_nobody_watches_samples(daemon_factory: Any) -> None:
    """Issue 31: unwatched, the sim is polled at half its 60 s sensor buffer (6 s at speed 5); a
    status subscriber brings heartbeat-rate polls, a samples subscriber the fast period; leaving
    restores the quiet one."""
    import time

    d = daemon_factory("--speed", "5").start()

    def interval_becomes(client: Any, value: float) -> bool:
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline:
            if client.call("status")["poll_interval_s"] == value:
                return True
            time.sleep(0.05)
        return False

    with d.client() as client:
        assert interval_becomes(client, 6.0)
        status_only = d.subscriber(protocol.subscription(d.node, "status"))
        assert interval_becomes(client, DaemonSettings().heartbeat_s)  # a current status, no fast polls
        sub = d.subscriber(protocol.subscription(d.node))
        assert interval_becomes(client, DaemonSettings().poll_interval_s)
        sub.close()
        assert interval_becomes(client, DaemonSettings().heartbeat_s)
        one_channel = d.subscriber(protocol.subscription(d.node, "samples") + b"DDR_AB")
        assert interval_becomes(client, DaemonSettings().poll_interval_s)
        one_channel.close()
        status_only.close()
        assert interval_becomes(client, 6.0)
