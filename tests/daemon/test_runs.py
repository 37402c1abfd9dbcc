"""Runs through the real daemon: window energy, model, refit, idle baselines, persistence across kill -9."""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
import pytest

from hdeem_watch.wire import protocol
from hdeem_watch.wire.client import ControlError

SPEED = 20.0
FAST_MODEL = {"HDEEM_WATCH_MODEL_MAX_REQUESTS": "100000"}
KERNELS = ("idle", "read", "triad", "copy", "assign", "add", "scale")


def _run(client: Any, kernel: str, seconds: float, elements: int = 2**26) -> dict[str, Any]:
    started = client.call("run.start", {"kernel": kernel, "name": f"t-{kernel}", "threads": 24,
                                        "elements": 0 if kernel == "idle" else elements, "repeat": 20,
                                        "metadata": {"test": True}})
    time.sleep(seconds)
    return client.call("run.stop", {"run_id": started["run_id"]}, timeout_s=60.0)


@pytest.mark.slow
def test_run_energy_model_and_refit(daemon_factory: Any, receive: Any) -> None:
    """Each stopped run has its window energy per channel, the model energies and a refit; the fit improves."""
    d = daemon_factory("--speed", str(SPEED), **FAST_MODEL).start()
    sub = d.subscriber(protocol.subscription(d.node))
    time.sleep(0.3)  # subscribed before the first run starts
    with d.client(timeout_s=30.0) as client:
        records = [_run(client, kernel, 0.15) for kernel in KERNELS]
        listed = client.call("runs.list")["runs"]
        calib = client.call("calib.get")
        baselines = client.call("baseline.get")["channels"]
        with pytest.raises(ControlError) as info:
            client.call("run.stop", {"run_id": "r999"})
        assert info.value.code == "not-found"
        reset = client.call("calib.reset")
        after_reset = client.call("calib.get")
    assert reset["fit"] is None and reset["runs"] == 0 and reset["history"] == []
    assert after_reset["fit"] is None and after_reset["truth"]["simulated"] is True
    # The idle run (the first) is every channel's idle baseline, its mean the run's mean power.
    for channel, entry in baselines.items():
        assert entry["origin"] == "idle-run"
        assert entry["power_w"] == pytest.approx(records[0]["mean_power_w"][channel], rel=1e-9)
    stream = receive(sub, 5.0, until=lambda ms: any(m.kind == "calib" and m.header["fit"]
                                                    and m.header["fit"]["n_runs"] == len(KERNELS) for m in ms))
    sub.close()
    for i, rec in enumerate(records):
        assert rec["state"] == "done" and rec["kernel"] in KERNELS
        assert 0.9 * 0.15 * SPEED < rec["window_s"] < 30.0  # the sleep, plus the stop latency on a loaded machine
        dram = [rec["energy_j"][c] for c in ("DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH")]
        assert all(e > 0 for e in dram)
        assert rec["dram_energy_j"] == pytest.approx(sum(dram), rel=1e-12)
        for channel, energy in rec["energy_j"].items():
            assert rec["mean_power_w"][channel] * rec["window_s"] == pytest.approx(energy, rel=0.05)
        assert rec["model_error"] is None, rec["model_error"]
        assert rec["model"]["datasheet_j"] > 0
        if i > 0:  # a fit exists from the earlier runs: the model predicts this one with it
            assert rec["model"]["calibrated_j"] > 0 and rec["model"]["predicted_j"] > 0
        assert rec["fit"]["n_runs"] == i + 1
    assert [r["run_id"] for r in listed] == [r["run_id"] for r in reversed(records)]
    final = records[-1]["fit"]
    assert final["error"]["after"] < final["error"]["before"]
    assert calib["fit"]["n_runs"] == len(KERNELS) and len(calib["history"]) == len(KERNELS)
    # run.start/run.stop publish run events, and each refit a calib message.
    events = [(m.header["event"], m.header["run"]["run_id"]) for m in stream if m.kind == "run"]
    assert events == [(event, rec["run_id"]) for rec in records for event in ("start", "stop")]
    stops = [m.header["run"] for m in stream if m.kind == "run" and m.header["event"] == "stop"]
    assert [s["dram_energy_j"] for s in stops] == pytest.approx([rec["dram_energy_j"] for rec in records])
    fits = [m.header["fit"]["n_runs"] for m in stream if m.kind == "calib" and m.header["fit"]]
    assert fits and fits[-1] == len(KERNELS)
    # Energy conservation: each window's energy per channel (from the source's cumulative totals) is
    # the integral of the very samples the stream carried inside the window.
    for rec in records:
        for channel, (first, last) in rec["samples_ns"].items():
            batches = [m for m in stream if m.kind == "samples" and m.channel == channel]
            period_s = 1.0 / batches[0].header["rate_hz"]
            t = np.concatenate([m.samples()[0] for m in batches])
            p = np.concatenate([m.samples()[1] for m in batches])
            assert t[0] <= first and t[-1] >= last, channel
            inside = (t > first) & (t <= last)
            assert float(p[inside].sum()) * period_s == pytest.approx(rec["energy_j"][channel], rel=1e-9, abs=1e-9)


@pytest.mark.slow
def test_idle_baseline_measure(daemon_factory: Any) -> None:
    """baseline.measure replies after its window with each channel's idle power, spread and sample count."""
    d = daemon_factory("--speed", str(SPEED), **FAST_MODEL).start()
    with d.client(timeout_s=10.0) as client:
        t0 = time.monotonic()
        body = client.call("baseline.measure", {"seconds": 4.0})
        elapsed = time.monotonic() - t0
        stored = client.call("baseline.get")
    assert elapsed < 4.0  # 4 s of sim time at speed 20
    # It closes at the first poll after 4 s of sim time: at speed 20 a 40 ms poll is 0.8 sim seconds.
    assert 4.0 <= body["window_s"] < 6.0
    for name, entry in body["channels"].items():
        assert entry["origin"] == "measured"  # nothing ran: the CPU channels' idle too (the TUI shows their "above")
        rate = 1000 if name == "BLADE" else 100
        # window_s is the DRAM channels' span. Each channel's window runs from its last sample at the
        # start poll to its sample covering the target: BLADE's samples fall due every 1 ms, the DRAM
        # channels' every 10 ms, so BLADE's span may differ by up to one DRAM period at each end.
        assert entry["n"] == pytest.approx(body["window_s"] * rate, abs=0.021 * rate + 2)
        assert entry["power_w"] > 0 and 0 <= entry["spread_w"] < entry["power_w"]
        assert stored["channels"][name] == entry


@pytest.mark.slow
def test_restart_after_kill9_keeps_history(daemon_factory: Any) -> None:
    """After kill -9 a restarted daemon has every run, the fit, the baselines; an open run is marked aborted."""
    d = daemon_factory("--speed", str(SPEED), **FAST_MODEL).start()
    with d.client(timeout_s=30.0) as client:
        client.call("baseline.measure", {"seconds": 2.0})
        done = [_run(client, k, 0.1) for k in ("idle", "triad", "read")]
        open_run = client.call("run.start", {"kernel": "copy", "elements": 2**20})["run_id"]
        before = {op: client.call(op) for op in ("calib.get", "baseline.get")}
    d.kill9()
    d.start()
    with d.client(timeout_s=30.0) as client:
        runs = {r["run_id"]: r for r in client.call("runs.list", {"full": True})["runs"]}
        calib = client.call("calib.get")
        baselines = client.call("baseline.get")
        new = client.call("run.start", {"kernel": "idle"})["run_id"]
        stopped_again = {rec["run_id"]: client.call("run.stop", {"run_id": rec["run_id"]}) for rec in done}
    for rec in done:
        assert runs[rec["run_id"]]["dram_energy_j"] == rec["dram_energy_j"]
        assert stopped_again[rec["run_id"]]["fit"] == rec["fit"]  # runs.list sends summaries (no fit)
    assert runs[open_run]["state"] == "aborted"
    assert calib["fit"]["n_runs"] == before["calib.get"]["fit"]["n_runs"] == 3
    for name, value in before["calib.get"]["fit"]["currents"].items():
        assert math.isclose(calib["fit"]["currents"][name]["calibrated"], value["calibrated"], rel_tol=1e-9)
    assert calib["history"] == before["calib.get"]["history"]
    assert baselines["channels"].keys() == before["baseline.get"]["channels"].keys()
    assert int(new[1:]) == int(open_run[1:]) + 1
