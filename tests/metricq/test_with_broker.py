"""The MetricQ source against a real RabbitMQ, the manager stand-in and a real metricq Sink.

The source runs as the real command (``python -m hdeem_watch metricq-source``) on a real sim
daemon; a ZeroMQ subscriber of the test records the daemon's stream to compare with what the sink
receives.
"""

from __future__ import annotations

import asyncio
import json
import math
import subprocess
import sys
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zmq
import zmq.asyncio

from hdeem_watch.wire import protocol

pytest.importorskip("metricq")
#: one worker runs them all: they share one RabbitMQ node (conftest.rabbit_node), each in its own vhost
pytestmark = [pytest.mark.timeout(240), pytest.mark.xdist_group("metricq-broker")]

PREFIX = "test.hw"
CHANNELS = {"BLADE": ("blade", 1000.0), "CPU0": ("cpu0", 100.0), "CPU1": ("cpu1", 100.0),
            "DDR_AB": ("dram.ab", 100.0), "DDR_CD": ("dram.cd", 100.0), "DDR_EF": ("dram.ef", 100.0),
            "DDR_GH": ("dram.gh", 100.0)}
PAIRS = ("DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH")


class StreamRecorder:
    """Records the daemon's samples and baselines (the reference the sink is compared with)."""

    def __init__(self, endpoint: str) -> None:
        self.context = zmq.asyncio.Context()
        self.socket: Any = self.context.socket(zmq.SUB)
        self.socket.setsockopt(zmq.RCVHWM, 100_000)
        self.socket.connect(endpoint)
        self.socket.setsockopt(zmq.SUBSCRIBE, b"hw1/")
        self.samples: dict[str, dict[int, float]] = defaultdict(dict)
        self.baselines: dict[str, set[float]] = defaultdict(set)
        self.currents: dict[str, set[float]] = defaultdict(set)
        self.task = asyncio.get_running_loop().create_task(self._run())

    async def _run(self) -> None:
        while True:
            m = protocol.decode(await self.socket.recv_multipart())
            if m.kind == "samples" and m.channel:
                t, p = m.samples()
                self.samples[m.channel].update(zip(t.tolist(), p.tolist()))
            elif m.kind == "baseline":
                for ch, entry in m.header["channels"].items():
                    if entry.get("power_w") is not None:
                        self.baselines[ch].add(float(entry["power_w"]))
            elif m.kind == "calib" and m.header.get("fit"):
                for name, entry in m.header["fit"]["currents"].items():
                    self.currents[name].add(entry["calibrated"])

    async def close(self) -> None:
        self.task.cancel()
        await asyncio.gather(self.task, return_exceptions=True)
        self.socket.close(linger=0)
        self.context.term()


def start_source(tmp_path: Path, server: str, pub: str, *extra: str) -> tuple[subprocess.Popen[bytes], Path]:
    status = tmp_path / "metricq-status.json"
    with open(tmp_path / "source.err", "ab") as err:
        proc = subprocess.Popen(
            [sys.executable, "-m", "hdeem_watch", "metricq-source", "--server", server, "--stream", pub,
             "--prefix", PREFIX, "--token", "source-hw-test", "--status-file", str(status),
             "--status-interval", "0.3", "--reconnect-max", "2", *extra],
            stdout=subprocess.DEVNULL, stderr=err, env=daemon_env())
    return proc, status


def daemon_env() -> dict[str, str]:
    import os

    src = str(Path(__file__).resolve().parents[2] / "src")
    env = dict(os.environ)
    env["PYTHONPATH"] = src + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env


def read_status(path: Path) -> dict[str, Any]:
    try:
        return dict(json.loads(path.read_text()))
    except (OSError, ValueError):
        return {}


async def wait_for(check: Callable[[], bool], timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not check():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        await asyncio.sleep(0.1)


def stop(proc: subprocess.Popen[bytes]) -> int:
    proc.terminate()
    return proc.wait(timeout=30)


def expected_metrics() -> list[str]:
    power = [f"{PREFIX}.testnode.{path}.power" for path, _ in CHANNELS.values()]
    above = [f"{PREFIX}.testnode.{CHANNELS[p][0]}.above_baseline.power" for p in PAIRS]
    return power + above


@pytest.mark.slow
async def test_every_metric_arrives_with_its_metadata_and_the_daemon_values(
        tmp_path: Path, broker: Any, manager: Any, sim_daemon: Any, standin: Any) -> None:
    recorder = StreamRecorder(sim_daemon.pub)
    proc, status_path = start_source(tmp_path, broker.url, sim_daemon.pub)
    sink = standin.RecordingSink(broker.url)
    try:
        with sim_daemon.client(timeout_s=20.0) as daemon:  # one run: the daemon fits the currents
            run_id = daemon.call("run.start", {"kernel": "triad", "threads": 2, "elements": 2**24})["run_id"]
            await asyncio.sleep(1.5)  # >= 1 s: shorter runs are recorded but not fitted
            daemon.call("run.stop", {"run_id": run_id})
            fit = daemon.call("calib.get")["fit"]
        assert fit is not None
        currents = [f"{PREFIX}.testnode.dram.calibrated.{name}.current" for name in fit["currents"]]
        wanted = expected_metrics() + currents
        await wait_for(lambda: all(m in manager.metadata for m in wanted), 60, "the source's declarations")
        meta = manager.metadata[currents[0]]
        assert (meta["unit"], meta["scope"], meta["rate"]) == ("A", "next", 0.1)
        for channel, (path, rate) in CHANNELS.items():
            meta = manager.metadata[f"{PREFIX}.testnode.{path}.power"]
            assert (meta["unit"], meta["rate"], meta["scope"]) == ("W", rate, "last")
            assert meta["source"] == "source-hw-test" and "testnode" in meta["description"]
            assert meta["channel"] == channel
        for pair in PAIRS:
            meta = manager.metadata[f"{PREFIX}.testnode.{CHANNELS[pair][0]}.above_baseline.power"]
            assert (meta["unit"], meta["rate"]) == ("W", 100.0) and "baseline" in meta["description"]
        assert manager.registered[0] == "source-hw-test"

        await sink.connect()
        response = await sink.subscribe(wanted)
        assert response["metrics"][wanted[0]]["unit"] == "W"  # the sink sees the metadata too
        await asyncio.sleep(3.0)  # 2 s of samples checked one by one (the last second may still travel)
        t_stop = time.time_ns()
        await asyncio.sleep(1.0)  # anything published up to t_stop has arrived within this second

        for channel, (path, _) in CHANNELS.items():
            t, v = sink.series(f"{PREFIX}.testnode.{path}.power")
            assert t.size > 0, channel
            assert np.all(np.diff(t) > 0), f"{channel}: times not increasing"
            reference = recorder.samples[channel]
            assert [reference.get(x) for x in t.tolist()] == v.tolist(), f"{channel}: values differ"
            expected_times = sorted(x for x in reference if t[0] <= x <= t_stop - 1_000_000_000)
            got = set(t.tolist())
            missing = [x for x in expected_times if x not in got]
            assert not missing, f"{channel}: {len(missing)} of {len(expected_times)} samples missing"
            for arrived_s, last_t_ns in sink.arrivals[f"{PREFIX}.testnode.{path}.power"]:
                assert arrived_s - last_t_ns / 1e9 < 1.0, f"{channel}: a chunk arrived more than 1 s late"
        for pair in PAIRS:
            t, v = sink.series(f"{PREFIX}.testnode.{CHANNELS[pair][0]}.above_baseline.power")
            assert t.size > 0
            power = np.array([recorder.samples[pair][x] for x in t.tolist()])
            known = ~np.isnan(v)
            baselines = power[known] - v[known]
            assert all(any(abs(b - k) < 1e-9 for k in recorder.baselines[pair]) for b in baselines), pair
        for name, metric in zip(fit["currents"], currents):
            t, v = sink.series(metric)
            assert t.size >= 2, f"{name}: the calib re-publications every 0.5 s"
            published = recorder.currents[name]  # None (unknown) arrives as NaN
            assert all(x in published or (math.isnan(x) and None in published) for x in v.tolist()), name
        assert max(manager.declarations.values()) == 1, "a metric declared again without a change"
        status = read_status(status_path)
        assert status["broker"] == "connected" and status["daemon"] == "streaming"
        assert status["points_dropped"] == 0 and status["nodes"] == 1
    finally:
        await sink.stop(silent=True)
        code = stop(proc)
        await recorder.close()
    assert code == 0, (tmp_path / "source.err").read_text()
    final = read_status(status_path)  # stopped: what was read went out first
    assert final["broker"] == "stopped" and final["points_waiting"] == 0
    assert final["points_sent"] == final["points_in"] > 0


@pytest.mark.slow
async def test_broker_down_and_restarted_mid_stream(tmp_path: Path, broker: Any, manager: Any,
                                                    sim_daemon: Any, standin: Any) -> None:
    proc, status_path = start_source(tmp_path, broker.url, sim_daemon.pub)
    sink = standin.RecordingSink(broker.url)
    try:
        wanted = expected_metrics()
        await wait_for(lambda: all(m in manager.metadata for m in wanted), 60, "the declarations")
        await sink.connect()
        await sink.subscribe(wanted)
        blade = f"{PREFIX}.testnode.blade.power"
        await wait_for(lambda: sink.series(blade)[0].size > 0, 10, "data before the restart")

        await asyncio.to_thread(broker.stop)
        before = read_status(status_path)
        await wait_for(lambda: read_status(status_path).get("broker") == "down", 20, "the status to show the broker down")
        # Nothing blocks: the source keeps reading the stream, the daemon keeps answering at once.
        await wait_for(lambda: read_status(status_path).get("messages", 0) > before.get("messages", 0) + 50, 10,
                       "the source to keep reading while the broker is down")
        with sim_daemon.client(timeout_s=2.0) as client:
            t0 = time.monotonic()
            client.call("ping")
            assert time.monotonic() - t0 < 1.0
        assert read_status(status_path)["points_waiting"] > 0

        await asyncio.to_thread(broker.start)
        t_restart = time.time_ns()
        await wait_for(lambda: read_status(status_path).get("broker") == "connected", 60, "the reconnect")
        await wait_for(lambda: sink.series(blade)[0].size > 0 and sink.series(blade)[0][-1] > t_restart, 60,
                       "data after the restart at the sink")
        status = read_status(status_path)
        assert status["points_dropped"] == 0 and status["reconnects"] >= 1
        await wait_for(lambda: read_status(status_path).get("points_waiting", 1e9) < 5000, 20,
                       "the buffered points to be sent")
    finally:
        await sink.stop(silent=True)
        code = stop(proc)
    assert code == 0, (tmp_path / "source.err").read_text()


@pytest.mark.slow
async def test_source_started_before_the_broker_connects_when_it_comes(tmp_path: Path, standin: Any,
                                                                      sim_daemon: Any) -> None:
    broker = standin.Broker(tmp_path / "late-rabbit")
    proc, status_path = start_source(tmp_path, broker.url, sim_daemon.pub)
    manager = None
    try:
        await wait_for(lambda: read_status(status_path).get("broker") == "down", 20, "the status to show down")
        first = read_status(status_path)
        assert first["broker_failures"] >= 1 and first["last_error"]
        await wait_for(lambda: read_status(status_path).get("points_waiting", 0) > 1000, 10, "buffering")
        await asyncio.to_thread(broker.start)
        manager = standin.ManagerStandIn(broker.url)
        await manager.connect()
        await wait_for(lambda: read_status(status_path).get("broker") == "connected", 30, "the first connection")
        await wait_for(lambda: f"{PREFIX}.testnode.blade.power" in manager.metadata, 10, "the declarations")
        await wait_for(lambda: read_status(status_path).get("points_sent", 0) > 1000, 10, "the buffer sent")
    finally:
        if manager is not None:
            await manager.stop(silent=True)
        code = stop(proc)
        broker.close()
    assert code == 0, (tmp_path / "source.err").read_text()


@pytest.mark.slow
async def test_daemon_restart_is_survived(tmp_path: Path, broker: Any, manager: Any, sim_daemon: Any) -> None:
    proc, status_path = start_source(tmp_path, broker.url, sim_daemon.pub)
    try:
        await wait_for(lambda: read_status(status_path).get("points_sent", 0) > 1000, 60, "data flowing")
        assert await asyncio.to_thread(sim_daemon.terminate) == 0
        await wait_for(lambda: read_status(status_path).get("daemon") == "silent", 20, "the daemon shown silent")
        await asyncio.to_thread(sim_daemon.start)
        sent = read_status(status_path)["points_sent"]
        await wait_for(lambda: read_status(status_path).get("daemon") == "streaming", 20, "streaming again")
        await wait_for(lambda: read_status(status_path).get("points_sent", 0) > sent + 1000, 20, "data again")
        status = read_status(status_path)
        assert status["daemon_restarts"] >= 1 and status["broker"] == "connected"
    finally:
        code = stop(proc)
    assert code == 0, (tmp_path / "source.err").read_text()


def _kill_broker(broker: Any) -> None:
    """The broker crashes: SIGKILL to its process group (no clean shutdown, connections just drop)."""
    import os
    import signal

    os.killpg(broker.proc.pid, signal.SIGKILL)
    broker.proc.wait(timeout=10)


@pytest.mark.slow
async def test_a_broker_crash_is_survived_and_the_series_is_whole_once_the_sink_is_back(
        tmp_path: Path, broker: Any, manager: Any, sim_daemon: Any, standin: Any) -> None:
    """The broker is killed mid-stream (no clean shutdown) and restarted: the source keeps reading
    the daemon, buffers, drops nothing, reconnects and sends what waited. What the sink misses is
    what RabbitMQ could not route: the points in flight at the crash and those published before the
    sink (reconnecting on its own) had its queue again; from its first chunk after the restart on,
    every sample the daemon streamed arrives, in order, with its value. Measured here: the hole
    spans the outage plus the sink's reconnect delay (aio-pika's 5 s), nothing after it."""
    recorder = StreamRecorder(sim_daemon.pub)
    proc, status_path = start_source(tmp_path, broker.url, sim_daemon.pub)
    sink = standin.RecordingSink(broker.url)
    blade = f"{PREFIX}.testnode.blade.power"
    try:
        await wait_for(lambda: blade in manager.metadata, 60, "the declarations")
        await sink.connect()
        await sink.subscribe([blade])
        await wait_for(lambda: sink.series(blade)[0].size > 1000, 20, "data before the crash")
        t_kill = time.time_ns()
        await asyncio.to_thread(_kill_broker, broker)
        await wait_for(lambda: read_status(status_path).get("broker") == "down", 20, "the broker shown down")
        before = read_status(status_path)
        await wait_for(lambda: read_status(status_path).get("messages", 0) > before.get("messages", 0) + 50, 10,
                       "the source to keep reading while the broker is down")
        assert read_status(status_path)["points_waiting"] > 0
        back = sink.series(blade)[0].size  # points received before the crash
        await asyncio.to_thread(broker.start)  # the manager and the sink reconnect by themselves
        await wait_for(lambda: read_status(status_path).get("broker") == "connected", 60, "the reconnect")
        await wait_for(lambda: sink.series(blade)[0].size > back + 3000, 60, "3 s of data after the restart at the sink")
        await wait_for(lambda: read_status(status_path).get("points_waiting", 1e9) < 5000, 20, "the backlog sent")
        t, v = sink.series(blade)
        status = read_status(status_path)
    finally:
        await sink.stop(silent=True)
        code = stop(proc)
        await recorder.close()
    assert code == 0, (tmp_path / "source.err").read_text()
    assert status["points_dropped"] == 0 and status["reconnects"] >= 1 and status["points_waiting"] < 5000
    assert np.all(np.diff(t) > 0)
    reference = recorder.samples["BLADE"]
    got = dict(zip(t.tolist(), v.tolist()))
    assert all(got[x] == reference[x] for x in got)
    after = t[back:]  # the first chunk after the restart and everything since
    expected_after = [x for x in reference if after[0] <= x <= after[-1]]
    assert after.size > 1000 and all(x in got for x in expected_after), "a hole after the sink was back"
    hole = [x for x in reference if t[0] <= x < after[0] and x not in got]
    assert not hole or (t_kill - 1e9 <= hole[0] and hole[-1] < after[0])  # only the outage and the sink's return
