"""Reading the daemon's SQLite state: the numbers are the state's, the file is never changed, and a
newer schema's added tables are tolerated (or used, when known)."""

from __future__ import annotations

import hashlib
import json
import math
import sqlite3
from pathlib import Path

import pytest

from hdeem_watch.errors import InputError
from hdeem_watch.job_record import JobRecord
from hdeem_watch.report.state_reader import read_state


def _records(state_dir: Path) -> list[dict]:
    db = sqlite3.connect(state_dir / "state.db")
    try:
        return [json.loads(t) for (t,) in db.execute("SELECT record FROM runs ORDER BY seq")]
    finally:
        db.close()


def _last_fit(state_dir: Path) -> dict:
    db = sqlite3.connect(state_dir / "state.db")
    try:
        return json.loads(db.execute("SELECT fit FROM fits WHERE fit IS NOT NULL ORDER BY id DESC").fetchone()[0])
    finally:
        db.close()


def test_runs_are_the_states_finished_runs_with_their_energies(state_dir: Path) -> None:
    """Every finished run is read with its measured DRAM energy, window and datasheet-model energy."""
    records = [r for r in _records(state_dir) if r["state"] == "done"]
    data = read_state(state_dir)
    assert [r.run_id for r in data.runs] == [r["run_id"] for r in records]
    for run, record in zip(data.runs, records):
        assert run.measured_j == record["dram_energy_j"]
        assert run.window_s == record["window_s"]
        assert run.datasheet_j == record["model"]["datasheet_j"]
        assert run.channel_energy_j == {c: e for c, e in record["energy_j"].items() if c.startswith("DDR")}
    assert data.channels == ("DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH")


def test_calibrated_energy_is_the_latest_fits_in_sample_prediction(state_dir: Path) -> None:
    """The calibrated-model energy of each run (recomputed from its row and the latest fit's currents)
    equals what the fit itself reports for that run (``after_j``), and ``loo_j`` is the fit's."""
    fit = _last_fit(state_dir)
    by_name = {r["name"]: r for r in fit["runs"]}
    data = read_state(state_dir)
    assert data.fit is not None and data.fit.to_dict() == fit
    for run in data.runs:
        entry = by_name[f"{run.run_id}:{run.name}"]
        assert run.calibrated_j == pytest.approx(entry["after_j"], rel=1e-9)
        assert run.loo_j == pytest.approx(entry["loo_j"], rel=1e-12)


def test_baselines_come_from_idle_runs_per_dimm_pair(state_dir: Path) -> None:
    """Each finished idle run gives one baseline point per DIMM pair: its mean power there."""
    idle = [r for r in _records(state_dir) if r["kernel"] == "idle" and r["state"] == "done"]
    data = read_state(state_dir)
    points = [b for b in data.baselines if b.origin == "idle-run"]
    assert len(points) == 4 * len(idle)
    first = idle[0]
    ab = next(b for b in points if b.channel == "DDR_AB" and b.t_ns == first["t_stop_ns"])
    assert ab.power_w == first["mean_power_w"]["DDR_AB"]


def test_reading_never_changes_the_state(state_dir: Path) -> None:
    """The database is opened read-only: its bytes are the same after a read."""
    before = hashlib.sha256((state_dir / "state.db").read_bytes()).hexdigest()
    read_state(state_dir)
    assert hashlib.sha256((state_dir / "state.db").read_bytes()).hexdigest() == before
    assert sorted(p.name for p in state_dir.iterdir()) == ["state.db"]


def test_a_newer_schemas_tables_are_tolerated_and_jobs_and_pair_fits_are_used(state_dir: Path) -> None:
    """Unknown tables are ignored; a ``jobs`` table of JSON records and a ``group`` column of ``fits``
    (per-pair fits) are read."""
    fit = _last_fit(state_dir)
    db = sqlite3.connect(state_dir / "state.db")
    db.execute("CREATE TABLE something_new (x INTEGER)")
    db.execute("CREATE TABLE jobs (job_id TEXT PRIMARY KEY, record TEXT NOT NULL)")
    job = JobRecord(job_id="4711", node="taurusi1234", user="alice", uid=1000, nodes=("taurusi1234",), cpus=None,
                    t_start_ns=1, state="done", t_stop_ns=60 * 10**9, dram_energy_j=900.0,
                    dram_above_baseline_j=300.0, measured_s=60.0)
    db.execute("INSERT INTO jobs VALUES ('4711', ?)", (json.dumps(job.to_dict()),))
    db.execute("INSERT INTO jobs VALUES ('x', ?)", (json.dumps({"job_id": "x", "dram_energy_j": 5.0}),))
    db.execute('ALTER TABLE fits ADD COLUMN "group" TEXT')
    db.execute('INSERT INTO fits (t_ns, run_id, fit, "group") VALUES (?, ?, ?, ?)',
               (fit["time_ns"] + 1, "r29", json.dumps(fit), "DDR_CD"))
    db.commit()
    db.close()
    data = read_state(state_dir)
    assert [(j.job_id, j.above_baseline_j, j.window_s) for j in data.jobs] == [("4711", 300.0, 60.0)]
    assert list(data.pair_fits) == ["DDR_CD"]
    assert data.fit is not None and data.fit.to_dict() == fit  # the node fit stays the node's


def test_jobs_are_built_from_runs_with_a_slurm_job_id(state_dir: Path) -> None:
    """Runs announced inside a SLURM job (metadata ``slurm_job_id``) make a job record: their DRAM
    energy and what the idle baseline before them would have used in the same windows."""
    db = sqlite3.connect(state_dir / "state.db")
    rows = db.execute("SELECT run_id, record FROM runs WHERE kernel = 'triad'").fetchall()
    for run_id, text in rows:
        record = json.loads(text)
        record["metadata"]["slurm_job_id"] = "99"
        db.execute("UPDATE runs SET record = ? WHERE run_id = ?", (json.dumps(record), run_id))
    db.commit()
    db.close()
    data = read_state(state_dir)
    triads = [r for r in _records(state_dir) if r["kernel"] == "triad" and r["state"] == "done"]
    (job,) = data.jobs
    assert job.job_id == "99" and job.runs == len(triads)
    assert job.dram_energy_j == pytest.approx(sum(r["dram_energy_j"] for r in triads))
    assert math.isfinite(job.baseline_j) and 0 < job.baseline_j < job.dram_energy_j


def test_missing_or_foreign_state_is_one_line_of_input_error(tmp_path: Path) -> None:
    """No state.db, or a database without a runs table, is bad input naming the path."""
    with pytest.raises(InputError, match="no daemon state"):
        read_state(tmp_path)
    other = tmp_path / "state.db"
    sqlite3.connect(other).execute("CREATE TABLE t (x)").connection.close()
    with pytest.raises(InputError, match="not a hdeem-watch state"):
        read_state(tmp_path)
    other.write_bytes(b"this is not sqlite" * 100)
    with pytest.raises(InputError, match="cannot read the state database"):
        read_state(tmp_path)


def test_damaged_rows_are_left_out_and_said(state_dir: Path) -> None:
    """A run record or fit that is not JSON does not stop the report: it is left out and the page
    says how many; a daemon's quarantine table is counted too."""
    db = sqlite3.connect(state_dir / "state.db")
    db.execute("UPDATE runs SET record = '{broken' WHERE run_id = 'r3'")
    db.execute("UPDATE fits SET fit = 'not json' WHERE run_id = 'r2'")
    db.execute("CREATE TABLE quarantine (id INTEGER PRIMARY KEY, t_ns INTEGER, source TEXT, row_key TEXT, "
               "content TEXT, reason TEXT)")
    db.execute("INSERT INTO quarantine (t_ns, source, row_key, content, reason) VALUES (1, 'runs', 'r9', '{', 'bad')")
    db.commit()
    db.close()
    data = read_state(state_dir)
    assert "r3" not in [r.run_id for r in data.runs] and len(data.runs) == 28
    assert [h.fit for h in data.fit_history if h.run_id == "r2"] == [None]
    assert any("1 run record(s)" in n for n in data.notes)
    assert any("set 1 damaged row(s)" in n for n in data.notes)


def test_per_pair_fits_and_alarms_come_from_the_daemons_state(aged_state_dir: Path, tmp_path: Path) -> None:
    """Issue 28: a state of the current daemon holds a fit per DIMM pair (its per-group
    calibrators) and the drift alarm DDR_CD raised; the report reads and shows both (before: "node-level
    fits only", "no drift alarms")."""
    from hdeem_watch.report.build import build_report

    data = read_state(aged_state_dir)
    assert sorted(data.pair_fits) == ["DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH"]
    assert all(len(history) > 10 for history in data.pair_history.values())
    assert all(fit.currents["idd0"].calibrated_a > 0 for fit in data.pair_fits.values())
    assert [(a["group"], a["current"], a["direction"]) for a in data.alarms] == [("DDR_CD", "energy", "up")]
    written = build_report(data, tmp_path / "out", fmt="html")
    page = written.page.read_text()
    assert "node-level fits only" not in page and "No data: drift alarms" not in page
    assert "calibrated (DDR_CD)" in page or "DDR_CD" in page
    assert written.missing["fig2-currents"] == () and written.missing["fig4-aging"] == ()
    numbers = json.loads((tmp_path / "out" / "numbers.json").read_text())
    aging = next(v for k, v in numbers.items() if k.startswith("Aging"))
    assert [row[1:3] for row in aging["drift alarms"]["rows"]] == [["DDR_CD", "energy"]]
    fits = {row[0] for row in next(v for k, v in numbers.items() if k.startswith("Currents"))["currents"]["rows"]}
    assert fits == {"node", "DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH"}


def test_a_fits_row_that_is_no_fit_is_left_out_not_read_as_a_reset(state_dir: Path) -> None:
    """A fits row of valid JSON that is no object (a damaged row) is left out: the latest fit stays
    the latest, and the page does not say the calibrator was reset."""
    fit = _last_fit(state_dir)
    db = sqlite3.connect(state_dir / "state.db")
    db.execute("INSERT INTO fits (t_ns, run_id, fit) VALUES (?, ?, ?)", (fit["time_ns"] + 1, "r99", "[1, 2]"))
    db.commit()
    db.close()
    data = read_state(state_dir)
    assert data.fit is not None and data.fit.to_dict() == fit
    assert not any("reset" in note for note in data.notes)
