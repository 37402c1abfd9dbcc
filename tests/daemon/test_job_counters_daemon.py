"""A SLURM job on the real daemon process with memory-controller counters
(``hdeem-watch daemon --source sim --counters sim``): its stored record carries the counted commands
and the modelled DRAM energy by component (``model.source == "counters"``), which
``hdeem-watch jobs --job ID`` shows. The job's traffic is an opaque run inside it (the sim plays a
hidden access mix for a run without a kernel)."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from typing import Any

import pytest


@pytest.mark.slow
def test_a_job_with_counters_is_modelled_by_component(daemon_factory: Any) -> None:
    d = daemon_factory("--source", "sim", "--counters", "sim", "--speed", "16").start()
    with d.client(timeout_s=60) as client:
        client.call("job.start", {"job_id": "88", "user": "alice", "uid": 1000, "cpus": 4})
        run = client.call("run.start", {"threads": 24})  # the sim's opaque traffic, inside the job
        time.sleep(0.6)  # ~10 sim s: a few phases of the hidden mix, not all idle
        live = client.call("job.get", {"job_id": "88"})
        inner = client.call("run.stop", {"run_id": run["run_id"]})
        stopped = client.call("job.stop", {"job_id": "88", "exit_code": 0})
        stored = client.call("job.get", {"job_id": "88"})  # from the store now
    assert live["counters"] is not None and live["model"] is None and live["model_error"].startswith("running")
    assert stopped.pop("stored") is True and stored == stopped  # the stop's reply: the record and that it is on disk
    assert stored["state"] == "done" and stored["model_error"] is None, stored["model_error"]
    counters, model = stored["counters"], stored["model"]
    assert counters["source"] == "sim" and counters["status"] == "ok" and len(counters["channels"]) == 8
    assert counters["channels"] == stored["segments"][0]["counters"]["channels"]  # one segment: the same counts
    assert model["source"] == "counters" and model["datasheet_j"] > 0 and model["counts"]["act"] > 0
    for role in ("act", "cas_rd", "cas_wr"):  # the job's window holds the run's: every command the run made
        assert counters["channels"]["S0.imc0"][role] >= inner["counters"]["channels"]["S0.imc0"][role] > 0, role
    components = model["components_j"]["datasheet"]
    for name in ("act_j", "rd_j", "wr_j", "ref_j", "bg_act_j", "bg_pre_j"):
        assert components[name] > 0, name
    assert sum(components.values()) == pytest.approx(model["datasheet_j"], rel=1e-9)
    assert set(model["sensors"]) == {c for c in stored["energy_j"] if c.startswith("DDR")}
    shown = subprocess.run([sys.executable, "-m", "hdeem_watch", "jobs", "--connect", d.control, "--job", "88"],
                           capture_output=True, text=True, timeout=60, env=d.env)
    assert shown.returncode == 0, shown.stderr
    assert "model from counters" in shown.stdout and "by component" in shown.stdout and "refresh" in shown.stdout
    assert d.terminate() == 0
    as_json = json.loads(json.dumps(stored))
    assert as_json["model"]["split_j"]["datasheet"]["read"] > 0
