"""Fixtures of the TUI tests: real publishers on ipc sockets in a short temporary directory."""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest

from hdeem_watch.demo.fakenode import FakeNode


@pytest.fixture
def sock_dir() -> Iterator[Path]:
    """A short directory for ipc sockets (ipc paths are limited to ~100 bytes)."""
    path = Path(tempfile.mkdtemp(prefix="hwt-", dir="/tmp"))
    try:
        yield path
    finally:
        shutil.rmtree(path, ignore_errors=True)


@pytest.fixture
def fake_node(sock_dir: Path) -> Iterator[FakeNode]:
    """A wire-protocol publisher at HDEEM rates with a control socket."""
    node = FakeNode("fake1", f"ipc://{sock_dir}/f1-pub", f"ipc://{sock_dir}/f1-ctl").start_and_wait()
    try:
        yield node
    finally:
        node.stop()


def pytest_configure(config: pytest.Config) -> None:  # pragma: no cover - environment only
    os.environ.setdefault("TEXTUAL_ANIMATIONS", "none")


FROZEN_WALL_NS = 1_700_000_000_000_000_000
FROZEN_MONO_NS = 5_000_000_000


def build_frozen_snapshot(node: str = "taurusi6001", *, stale: bool = False, plot_cells: int = 32):  # type: ignore[no-untyped-def]
    """A deterministic snapshot: 60 s of HDEEM-shaped samples, baselines, runs and a fit, no live data."""
    import numpy as np

    from hdeem_watch.tui.model import NodeModel
    from hdeem_watch.wire import protocol

    model = NodeModel("ipc:///run/hdeem-watch/control.sock")
    seq = 0

    def put(kind: str, body: dict) -> None:
        nonlocal seq
        seq += 1
        topic = protocol.topic(node, kind)
        model.apply(protocol.decode(protocol.encode(topic, {"seq": seq, "node": node, "t_ns": FROZEN_WALL_NS, **body})), 0)

    t0 = FROZEN_WALL_NS - 60 * 10**9
    rates = {"DDR_AB": 100, "DDR_CD": 100, "DDR_EF": 100, "DDR_GH": 100, "CPU0": 100, "CPU1": 100, "BLADE": 1000}
    base = {"DDR_AB": 6.0, "DDR_CD": 5.5, "DDR_EF": 5.0, "DDR_GH": 5.2, "CPU0": 40.0, "CPU1": 30.0, "BLADE": 150.0}
    for i, (name, rate) in enumerate(rates.items()):
        t = t0 + np.arange(60 * rate, dtype=np.int64) * (10**9 // rate)
        phase = (t - t0) / 1e9
        busy = ((phase % 12.0) > 4.0) & ((phase % 12.0) < 10.0)
        power = base[name] * (1.0 + 0.8 * busy) + 0.25 * np.sin(phase * 3 + i)
        power = np.round(power / 0.125) * 0.125
        power[len(power) // 3] += 0.2 * base[name]  # a one-sample spike the envelope must keep
        frames = protocol.encode_samples(node, name, seq=0, rate_hz=rate, t_wall_ns=t, power_w=power,
                                         energy_j=1234.5, status="ok", t_ns=int(t[-1]))
        model.apply(protocol.decode(frames), 0)
    put("status", {"source": {"kind": "sim", "health": "ok"}, "process": {"cpu_percent": 0.7, "rss_bytes": 52_000_000},
                   "uptime_s": 3600.0, "run": None, "channels": {}})
    put("baseline", {"channels": {n: {"power_w": b, "spread_w": 0.12, "n": 1000, "t_ns": 0, "origin": "idle-run"}
                                  for n, b in base.items()}})
    kernels = ["idle", "read", "assign", "scale", "add", "triad", "copy", "selfscale"]
    for k, kernel in enumerate(kernels):
        measured = 7.7 if kernel == "idle" else 18.0 + k
        put("run", {"event": "stop", "run": {
            "run_id": f"r{k}", "state": "done", "name": f"{kernel}-24t", "kernel": kernel, "threads": 24, "window_s": 1.5,
            "dram_energy_j": measured, "metadata": {"simulated": True},
            "model": {"datasheet_j": measured * 2.02, "calibrated_j": measured * (1.0 + 0.01 * (k - 3))}}})
    put("run", {"event": "start", "run": {"run_id": "r9", "name": "read-12t", "kernel": "read", "threads": 12,
                                         "t_start_ns": FROZEN_WALL_NS - 700_000_000, "state": "running"}})
    names = {"idd0": (0.0622, 0.0471), "idd2n": (0.0578, 0.0279), "idd3n": (0.0856, 0.0182),
             "idd4r": (0.0972, 0.0965), "idd4w": (0.0883, 0.0664)}
    fit = {"currents": {n: {"datasheet": d, "calibrated": t * 1.03,
                            "ci95": [t * 1.03 - 0.0015, t * 1.03 + 0.0015], "identifiable": n != "idd3n"}
                        for n, (d, t) in names.items()},
           "error": {"before": 1.02, "after": 0.031, "loo": 0.048}, "n_runs": 8}
    history = [{"t_ns": i, "currents": {n: d - (d - t) * (1 - 0.7**i) for n, (d, t) in names.items()}} for i in range(12)]
    part = {"DDR_AB": 1.0, "DDR_CD": 1.25, "DDR_EF": 0.96, "DDR_GH": 1.04}
    alarm = {"group": "DDR_CD", "current": "energy", "kind": "residual-cusum", "statistic": 12.4, "threshold": 12.0,
             "time_ns": FROZEN_WALL_NS, "direction": "up"}

    def group(factor: float, dimms: list[int] | None, alarms: list[dict]) -> dict:
        currents = {n: {"datasheet": d, "calibrated": t * factor, "ci95": [t * factor - 0.002, t * factor + 0.002],
                        "identifiable": n != "idd3n"} for n, (d, t) in names.items()}
        return {"fit": {"currents": currents, "status": "ok", "error": {"loo": 0.02 * factor}, "n_runs": 8},
                "runs": 8, "dimms_per_socket": dimms, "alarms": alarms}

    groups = {g: group(f, [2, 0] if g in ("DDR_AB", "DDR_CD") else [0, 2], [alarm] if g == "DDR_CD" else [])
              for g, f in part.items()}
    put("calib", {"fit": fit, "history": history, "truth": {"simulated": True, "mean_currents_a": {n: t for n, (_, t) in names.items()}},
                  "suggest": [["idle-24t", 0.4]], "groups": groups, "total": group(1.06, None, []), "alarms": [alarm]})
    now_mono = FROZEN_MONO_NS + (10 * 10**9 if stale else 0)
    model.last_rx_mono_ns = FROZEN_MONO_NS
    return model.snapshot(now_mono_ns=now_mono, now_wall_ns=FROZEN_WALL_NS, window_s=60.0, width=2 * plot_cells)


@pytest.fixture
def frozen_snapshot():  # type: ignore[no-untyped-def]
    """The builder of deterministic snapshots (``frozen_snapshot(node, stale=False)``)."""
    return build_frozen_snapshot


@pytest.fixture
def sim_daemon():  # type: ignore[no-untyped-def]
    """A real ``hdeem-watch daemon --source sim`` subprocess on ipc endpoints (stopped afterwards)."""
    from hdeem_watch.demo.daemon import DemoDaemon

    daemon = DemoDaemon(node="pilot", start_timeout_s=60.0).start()
    try:
        yield daemon
    finally:
        daemon.stop()
