"""The headline of issue 17 on the real daemon process: ``hdeem-watch daemon --source sim --counters sim``.

A run started without a kernel gets a model energy from counters in its ``run.stop`` result
(``model.source == "counters"``), and the stream carries per-channel command rates (``counters``
topic, each heartbeat) that show the job's traffic. The daemon records its samples and counters;
a second daemon replays them (``--source replay --counters replay``) and models a window from the
replayed counters. (One test: each daemon start costs seconds.)
"""

from __future__ import annotations

import time

import pytest

from hdeem_watch.daemon.counters.record import counters_path, read_counter_recording
from hdeem_watch.wire import protocol


@pytest.mark.slow
def test_an_opaque_job_on_the_sim_daemon_is_modelled_from_counters_and_replays(daemon_factory, receive,
                                                                               tmp_path) -> None:
    record = tmp_path / "rec.csv"
    daemon = daemon_factory("--counters", "sim", "--speed", "4", "--record", str(record)).start()
    sub = daemon.subscriber(b"hw1/" + daemon.node.encode() + b"/counters")
    with daemon.client(timeout_s=60) as client:
        started = client.call("run.start", {"threads": 24, "name": "opaque"})
        assert started["run"]["kernel"] == "job"
        time.sleep(1.5)
        messages = receive(sub, 3.0, until=lambda ms: any(
            (m.header.get("channels") or {}).get("S0.imc0", {}).get("rd_per_s") for m in ms))
        stopped = client.call("run.stop", {"run_id": started["run_id"]})
    sub.close()
    assert messages and all(m.kind == "counters" for m in messages)
    header = messages[-1].header
    assert header["source"] == "sim" and header["generation"] == "haswell-ep" and header["status"] == "ok"
    channel = header["channels"]["S0.imc0"]
    assert channel["sensor"] == "DDR_AB" and channel["rd_per_s"] > 0 and 0 <= channel["powerdown_share"] <= 1
    assert stopped["model_error"] is None, stopped["model_error"]
    assert stopped["model"]["source"] == "counters" and stopped["model"]["datasheet_j"] > 0
    assert stopped["counters"]["status"] == "ok" and len(stopped["counters"]["channels"]) == 8
    assert "counters" in protocol.KINDS
    assert daemon.terminate() == 0
    header, snapshots = read_counter_recording(counters_path(record))
    assert header["kind"] == "sim" and len(snapshots) >= 3

    replay = daemon_factory("--source", "replay", "--replay-file", str(record), "--counters", "replay",
                            "--speed", "4", name="play").start()
    with replay.client(timeout_s=60) as client:
        run = client.call("run.start", {"threads": 12})
        time.sleep(1.0)
        replayed = client.call("run.stop", {"run_id": run["run_id"]})
    assert replay.terminate() == 0
    assert replayed["counters"]["source"] == "replay"
    assert replayed["model"] is not None and replayed["model"]["source"] == "counters", replayed["model_error"]
