"""The one job record (issue #26): every job record a real daemon sent (tests/data/wire, main at
``aa2cb5a``) or stored (tests/data/state, main at ``70a5feb``), full or summary, reads into
:class:`JobRecord` and writes back to the same bytes; damaged records read with their unknowns
named, never 0, and the CLI and the report show them as unknown."""

from __future__ import annotations

import base64
import json
import math
from pathlib import Path
from typing import Any

import pytest

from hdeem_watch.cli.jobs import table, total_line
from hdeem_watch.daemon.jobs.records import job_summary
from hdeem_watch.daemon.store.checks import check_open_job
from hdeem_watch.job_record import JOB_FIELDS, JobRecord
from hdeem_watch.wire.json_codec import dumps

DATA = Path(__file__).resolve().parents[1] / "data"


def _recorded_jobs() -> list[tuple[str, dict[str, Any], bytes]]:
    """Every job record the recorded daemon sent or stored: (where, record, the frame or row it was in)."""
    out = []
    for line in (DATA / "wire" / "stream.jsonl").read_text(encoding="utf-8").splitlines():
        topic, header, _payload = (base64.b64decode(f) for f in json.loads(line)["frames"])
        if topic.endswith(b"/job"):
            body = json.loads(header)
            out.append((f"job topic {body['event']}", body["job"], header))
    for line in (DATA / "wire" / "control.jsonl").read_text(encoding="utf-8").splitlines():
        exchange = json.loads(line)
        request, reply = base64.b64decode(exchange["request"]), base64.b64decode(exchange["reply"])
        op = json.loads(request).get("op") if request.startswith(b'{"id"') else None
        if op in ("job.start", "job.stop"):
            out.append((f"{op} reply", json.loads(reply)["result"], reply))
        elif op == "job.list":
            out += [(f"job.list entry {i}", job, reply) for i, job in enumerate(json.loads(reply)["result"]["jobs"])]
    for line in (DATA / "state" / "rows.jsonl").read_text(encoding="utf-8").splitlines():
        row = json.loads(line)
        if row["table"] == "jobs":
            out.append((f"jobs row {row['key'].split('@')[0]}", json.loads(row["json"]), row["json"].encode()))
    return out


RECORDED = _recorded_jobs()


def test_the_recording_holds_full_summary_running_and_finished_jobs() -> None:
    assert {"running", "done"} <= {job["state"] for _w, job, _f in RECORDED}
    assert any("segments" in job for _w, job, _f in RECORDED) and any("n_segments" in job for _w, job, _f in RECORDED)


@pytest.mark.parametrize(("where", "job", "frame"), RECORDED, ids=[w for w, _j, _f in RECORDED])
def test_a_recorded_job_reads_and_writes_back_to_the_same_bytes(where: str, job: dict[str, Any], frame: bytes) -> None:
    record = JobRecord.from_dict(job, strict=True)
    written = dumps(record.to_dict())
    assert written == dumps(job)
    assert written in frame  # the very bytes the daemon sent or stored
    assert record.dram_energy_j == job["dram_energy_j"] or (job["dram_energy_j"] is None
                                                             and math.isnan(record.dram_energy_j))


def test_a_full_record_and_its_summary_agree() -> None:
    """The summary the topic and ``job.list`` carry is the record without segments: the parser
    reads both to the same totals, and the count of segments either way."""
    _where, job, _frame = next(r for r in RECORDED if r[0].startswith("job.stop"))
    full, summary = JobRecord.from_dict(job), JobRecord.from_dict(job_summary(job))
    assert full.segments and not summary.segments
    assert full.segment_count == summary.segment_count == len(job["segments"])
    assert (full.dram_energy_j, full.measured_s, full.status) == (summary.dram_energy_j, summary.measured_s,
                                                                   summary.status)
    assert dumps(summary.to_dict()) == dumps(job_summary(job))
    assert tuple(k for k in full.keys if k in JOB_FIELDS) == JOB_FIELDS


def test_missing_and_ill_typed_fields_are_unknown_and_named_never_zero() -> None:
    record = JobRecord.from_dict({"job_id": "7", "state": "done", "node": "n1", "uid": "1000",
                                  "dram_energy_j": "12", "energy_j": {"DDR_AB": "x"}, "measured_s": None,
                                  "segments": [{"t_start_ns": 1}], "status": "ok"})
    assert math.isnan(record.dram_energy_j) and math.isnan(record.measured_s) and record.uid is None
    assert record.energy_j == {} and record.segments == () and record.t_start_ns is None
    assert math.isnan(record.dram_mean_power_w)
    assert record.problems == (
        "t_start_ns: missing",
        "energy_j = \"{'DDR_AB': 'x'}\": expected an object of numbers",
        "uid = '1000': expected an integer",
        "segments[0]: not a segment (KeyError('t_stop_ns'); left out)",
        "dram_energy_j = '12': expected a number",
    )
    with pytest.raises(ValueError, match="job 7: node: missing; t_start_ns: missing"):
        JobRecord.from_dict({"job_id": "7", "state": "done"}, strict=True)
    with pytest.raises(ValueError, match="not a job record: job_id None"):
        JobRecord.from_dict({"state": "done"})


def test_the_store_check_refuses_a_running_job_it_could_not_resume() -> None:
    """A stored running job without its start is not resumed as if it started at 0: the check names it."""
    _where, job, _frame = next(r for r in RECORDED if r[0].startswith("job.start"))
    check_open_job(job)
    with pytest.raises(ValueError, match="t_start_ns = 'soon': expected an integer"):
        check_open_job({**job, "t_start_ns": "soon"})


def test_the_jobs_table_shows_unknown_as_unknown_and_an_unreadable_entry_in_one_line() -> None:
    """``hdeem-watch jobs``: an ill-typed energy is "–", never 0.0; a job entry that is no job
    record is one line naming why; the total over nodes is unknown when one node's is."""
    _where, job, _frame = next(r for r in RECORDED if r[0].startswith("job.list"))
    answers = [{"node": "n1", "ok": True, "op": "job.get", "jobs": [job]},
               {"node": "n2", "ok": True, "op": "job.get", "jobs": [{**job, "dram_energy_j": "lots"}]},
               {"node": "n3", "ok": True, "op": "job.get", "jobs": [{"job_id": 4242}]}]
    lines = table(answers)
    assert f"{job['dram_energy_j']:.1f}" in lines[1]
    n2 = next(line for line in lines if line.startswith("n2"))
    assert n2[49:58].strip() == "–" and lines[1][49:58].strip() == f"{job['dram_energy_j']:.1f}"  # DRAM J
    assert any(line.startswith("n3") and "unreadable job entry: not a job record: job_id 4242" in line
               for line in lines)
    assert "unknown: 2 of 3 nodes missing" in (total_line(answers) or "")
