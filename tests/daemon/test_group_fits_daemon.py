"""Per-sensor-group fits through a real sim daemon (a subprocess, ipc endpoints in a temporary
directory): ``calib.get`` and ``hdeem-watch calib show --json`` carry one fit per DIMM pair beside the
node fit; a 10 ms run is recorded, not fitted, and says why; ``calib.reset`` of one group keeps the rest."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import zmq

from hdeem_watch.cli import main
from hdeem_watch.wire import protocol
from hdeem_watch.wire.client import ControlClient, ControlError, DaemonUnreachable

SRC = Path(__file__).resolve().parents[2] / "src"
PAIRS = {"DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH"}


def start_daemon(tmp_path: Path, speed: float) -> tuple[subprocess.Popen[bytes], str]:
    """A sim daemon at ``speed``; returns it and its control endpoint once it answers."""
    control = f"ipc://{tmp_path}/c.sock"
    env = {k: v for k, v in os.environ.items() if not k.startswith("HDEEM_WATCH_")}
    env["PYTHONPATH"] = str(SRC) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    with open(tmp_path / "daemon.err", "wb") as err:
        proc = subprocess.Popen([sys.executable, "-m", "hdeem_watch", "daemon", "--source", "sim", "--speed", str(speed),
                                 "--pub", f"ipc://{tmp_path}/p.sock", "--control", control,
                                 "--state-dir", str(tmp_path / "state"), "--node", "grouptest"],
                                env=env, stdout=subprocess.DEVNULL, stderr=err)
    deadline = time.monotonic() + 30
    with ControlClient(control, timeout_s=1.0) as client:
        while True:
            assert proc.poll() is None, (tmp_path / "daemon.err").read_text()
            try:
                client.call("ping")
                return proc, control
            except DaemonUnreachable:
                assert time.monotonic() < deadline
                time.sleep(0.05)


@pytest.fixture
def daemon(tmp_path: Path) -> Iterator[str]:
    """A sim daemon at speed 20 (a 0.1 s wait is a 2 s run: 200 samples per DDR channel, twice the guard rail)."""
    proc, control = start_daemon(tmp_path, 20)
    try:
        yield control
    finally:
        proc.terminate()
        proc.wait(timeout=15)


@pytest.mark.slow
def test_calib_get_and_calib_show_have_a_fit_per_pair(daemon: str, tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    context = zmq.Context.instance()
    sub = context.socket(zmq.SUB)
    sub.setsockopt(zmq.LINGER, 0)
    sub.connect(f"ipc://{tmp_path}/p.sock")
    sub.setsockopt(zmq.SUBSCRIBE, protocol.subscription("grouptest", "calib"))
    with ControlClient(daemon, timeout_s=30.0) as client:
        for kernel, threads in (("idle", 1), ("read", 4), ("triad", 24), ("copy", 12), ("read", 24),
                                ("assign", 6), ("idle", 1), ("add", 18)):
            run = client.call("run.start", {"kernel": kernel, "threads": threads, "elements": 1 << 22, "repeat": 2})
            time.sleep(0.1)
            done = client.call("run.stop", {"run_id": run["run_id"]})
            assert done["model_error"] is None, done["model_error"]
            assert set(done["model"]["group_observations"]) == PAIRS
        body = client.call("calib.get")
        assert set(body["groups"]) == PAIRS and body["total"]["runs"] == 8 and body["runs"] == 8
        assert all(g["runs"] == 8 and g["fit"]["n_runs"] == 8 for g in body["groups"].values())
        assert body["groups"]["DDR_EF"]["dimms_per_socket"] == [0, 2]
        # the stream's calib body: the same groups, and the groups' total fit beside the header's node name
        deadline = time.monotonic() + 15
        while True:
            assert sub.poll(int(max(0.0, deadline - time.monotonic()) * 1000)), "no calib message"
            message = protocol.decode(sub.recv_multipart())
            if message.header.get("runs") == 8:
                break
        assert message.header["node"] == "grouptest" and message.header["total"]["runs"] == 8
        assert set(message.header["groups"]) == PAIRS
        sub.close()

        with pytest.raises(ControlError) as bad:
            client.call("calib.reset", {"group": 3})
        assert bad.value.code == "bad-args" and "args.group" in str(bad.value)
        with pytest.raises(ControlError) as unknown:
            client.call("calib.reset", {"group": "DDR_XY"})
        assert unknown.value.code == "bad-args" and "DDR_XY" in str(unknown.value)
        after = client.call("calib.reset", {"group": "DDR_CD"})
        assert after["groups"]["DDR_CD"]["runs"] == 0 and after["groups"]["DDR_AB"]["runs"] == 8
        assert after["runs"] == 8 and after["fit"] is not None

    assert main(["calib", "show", "--connect", daemon, "--json"]) == 0
    shown = json.loads(capsys.readouterr().out)
    assert set(shown["groups"]) == PAIRS | {"total"}  # the groups' sum beside them; "node" = the daemon's node fit
    assert shown["node"]["fit"]["n_runs"] == 8 and shown["groups"]["total"]["fit"]["n_runs"] == 8
    assert shown["groups"]["DDR_AB"]["fit"]["n_runs"] == 8 and shown["groups"]["DDR_CD"]["fit"] is None
    assert set(shown["groups"]["DDR_GH"]["fit"]["currents"]) >= {"idd0", "idd3n", "idd4r", "idd4w"}


@pytest.mark.slow
def test_a_10ms_run_is_recorded_not_fitted_and_says_why(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    proc, control = start_daemon(tmp_path, 1)
    try:
        with ControlClient(control, timeout_s=30.0) as client:
            run = client.call("run.start", {"kernel": "triad", "threads": 24, "elements": 1 << 22, "repeat": 1})
            time.sleep(0.01)
            done = client.call("run.stop", {"run_id": run["run_id"]})
            assert done["window_s"] < 0.5, done["window_s"]  # sanity: the run was short
            assert done["fit"] is None and done["model"] is not None
            assert done["model_error"].startswith("not calibrated: ") and "samples of DDR_" in done["model_error"]
            assert "at least 100 are needed" in done["model_error"]
            stored = client.call("runs.list", {"limit": 1})["runs"][0]
            assert stored["run_id"] == run["run_id"] and stored["model_error"] == done["model_error"]
            body = client.call("calib.get")
            assert body["runs"] == 0 and all(g["runs"] == 0 for g in body["groups"].values())
        # bench warns about a run the daemon did not calibrate with
        assert main(["bench", "--kernels", "read", "--threads", "1", "--elements", "4096", "--repeat", "1",
                     "--daemon", control]) == 0
        err = capsys.readouterr().err
        assert "hdeem-watch bench: warning: 1 of 1 run was not calibrated" in err and "samples of DDR_" in err
        assert "make them longer: drop --repeat" in err
    finally:
        proc.terminate()
        proc.wait(timeout=15)
