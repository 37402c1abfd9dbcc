"""The one run record (issue #26): what the daemon of main at ``aa2cb5a`` sent (recorded in
tests/data/wire) reads into :class:`RunRecord` and writes back to the same bytes; old and partial
records read with their unknowns named, never as 0."""

from __future__ import annotations

import base64
import json
import math
from pathlib import Path
from typing import Any

import pytest

from hdeem_watch.daemon.book.runs import run_summary
from hdeem_watch.run_record import WIRE_FIELDS, RunRecord
from hdeem_watch.wire.json_codec import dumps

DATA = Path(__file__).resolve().parents[1] / "data" / "wire"


def _recorded_records() -> list[tuple[str, dict[str, Any], bytes]]:
    """Every full run record the recorded daemon sent: (where, record, the frame it was in)."""
    out = []
    for line in (DATA / "stream.jsonl").read_text(encoding="utf-8").splitlines():
        topic, header, _payload = (base64.b64decode(f) for f in json.loads(line)["frames"])
        if topic.endswith(b"/run"):
            body = json.loads(header)
            out.append((f"run topic {body['event']}", body["run"], header))
    for line in (DATA / "control.jsonl").read_text(encoding="utf-8").splitlines():
        exchange = json.loads(line)
        request_frame, reply = base64.b64decode(exchange["request"]), base64.b64decode(exchange["reply"])
        if not request_frame.startswith(b'{"id"'):  # the recording's malformed request
            continue
        request, result = json.loads(request_frame), json.loads(reply).get("result")
        if request.get("op") == "run.start":
            out.append(("run.start reply", result["run"], reply))
        elif request.get("op") == "run.stop" and isinstance(result, dict):
            out.append(("run.stop reply", result, reply))
    return out


RECORDED = _recorded_records()


def test_the_recording_holds_running_and_finished_runs() -> None:
    states = {record["state"] for _where, record, _frame in RECORDED}
    assert {"running", "done"} <= states and len(RECORDED) >= 4


@pytest.mark.parametrize(("where", "record", "frame"), RECORDED, ids=[w for w, _r, _f in RECORDED])
def test_a_recorded_record_reads_and_writes_back_to_the_same_bytes(where: str, record: dict[str, Any],
                                                                   frame: bytes) -> None:
    parsed = RunRecord.from_dict(record, strict=where != "run.stop reply")  # that reply adds "stored"
    written = dumps(parsed.to_dict())
    assert written == dumps(record)
    assert written in frame  # the very bytes the daemon sent
    assert parsed.problems == ()


def test_a_recorded_finished_run_reads_typed() -> None:
    done = next(r for w, r, _f in RECORDED if w == "run topic stop")
    parsed = RunRecord.from_dict(done)
    assert parsed.state == "done" and parsed.threads == 4 and parsed.window_s == done["window_s"]
    assert parsed.dram_energy_j == done["dram_energy_j"] and parsed.figures.datasheet_j == done["model"]["datasheet_j"]
    summary = RunRecord.from_dict(run_summary(done))  # a runs.list entry reads the same figures
    assert summary.figures == parsed.figures and summary.dram_energy_j == parsed.dram_energy_j
    assert summary.problems == ()


def test_unknown_fields_are_named_never_zero() -> None:
    old = RunRecord.from_dict({"run_id": "r7", "state": "done", "kernel": "copy", "threads": "many",
                               "energy_j": {"DDR_AB": None}})
    assert old.threads is None and old.elements is None and math.isnan(old.dram_energy_j or 0.0)
    assert math.isnan(old.window_s or 0.0) and old.energy_j is not None and math.isnan(old.energy_j["DDR_AB"])
    assert "threads = 'many': expected an integer" in old.problems and "elements: missing" in old.problems
    assert "window_s: missing" in old.problems and "dram_energy_j: missing" in old.problems
    assert math.isnan(old.figures.datasheet_j) and old.name == "copy"
    with pytest.raises(ValueError, match="r7: threads = 'many'"):
        RunRecord.from_dict({"run_id": "r7", "state": "done", "kernel": "copy", "threads": "many"}, strict=True)
    running = RunRecord.from_dict({"run_id": "r8", "state": "running", "kernel": "idle", "threads": 1,
                                   "elements": 0, "repeat": 1, "metadata": {}, "t_start_ns": 5})
    assert running.window_s is None and running.dram_energy_j is None and running.problems == ()


@pytest.mark.parametrize("data", [{"state": "done"}, {"run_id": "r1", "state": "finished"}, ["r1"]])
def test_what_is_not_a_run_record_is_refused(data: Any) -> None:
    with pytest.raises(ValueError, match="not a run record"):
        RunRecord.from_dict(data)


def test_keys_of_a_newer_daemon_survive_a_round_trip() -> None:
    done = dict(next(r for w, r, _f in RECORDED if w == "run topic stop"))
    newer = {**done, "power_cap_w": 200.0}
    again = RunRecord.from_dict(newer).to_dict()
    assert list(again) == [*WIRE_FIELDS, "power_cap_w"] and again["power_cap_w"] == 200.0
