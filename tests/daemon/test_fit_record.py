"""The one fit record (issue #26): every fit a real daemon sent (tests/data/wire, main at
``aa2cb5a``) or stored (tests/data/state, main at ``70a5feb``) reads into :class:`FitRecord` and
writes back to the same bytes; partial and damaged fits read with their unknowns named, never 0."""

from __future__ import annotations

import base64
import json
import math
from pathlib import Path
from typing import Any

import pytest

from hdeem_watch.daemon.book.runs import run_summary
from hdeem_watch.daemon.store.checks import check_fit
from hdeem_watch.fit_record import FIT_FIELDS, CurrentFit, FitRecord
from hdeem_watch.tui.records import calib_view
from hdeem_watch.wire.json_codec import dumps

DATA = Path(__file__).resolve().parents[1] / "data"


def _calib_fits(body: dict[str, Any], where: str) -> list[tuple[str, dict[str, Any]]]:
    """The node fit, each pair's fit and the groups' total fit of a ``calib`` body."""
    out = [(f"{where} fit", body["fit"])] if body.get("fit") else []
    out += [(f"{where} groups.{name}.fit", entry["fit"]) for name, entry in body["groups"].items() if entry["fit"]]
    return out + ([(f"{where} total.fit", body["total"]["fit"])] if body["total"]["fit"] else [])


def _recorded_fits() -> list[tuple[str, dict[str, Any], bytes]]:
    """Every fit the recorded daemon sent or stored: (where, fit, the frame or row it was in)."""
    out = []
    for line in (DATA / "wire" / "stream.jsonl").read_text(encoding="utf-8").splitlines():
        topic, header, _payload = (base64.b64decode(f) for f in json.loads(line)["frames"])
        body = json.loads(header)
        if topic.endswith(b"/calib"):
            out += [(where, fit, header) for where, fit in _calib_fits(body, f"calib topic seq {body['seq']}")]
        elif topic.endswith(b"/run") and body["run"].get("fit"):
            out.append((f"run topic {body['event']}", body["run"]["fit"], header))
    for line in (DATA / "wire" / "control.jsonl").read_text(encoding="utf-8").splitlines():
        exchange = json.loads(line)
        reply = base64.b64decode(exchange["reply"])
        if b'"calib.get"' in base64.b64decode(exchange["request"]):
            out += [(where, fit, reply) for where, fit in _calib_fits(json.loads(reply)["result"], "calib.get")]
    for line in (DATA / "state" / "rows.jsonl").read_text(encoding="utf-8").splitlines():
        row = json.loads(line)
        if row["table"] == "fits":
            out.append((f"fits row {row['key']}", json.loads(row["json"]), row["json"].encode()))
        elif row["table"] == "runs" and json.loads(row["json"]).get("fit"):
            out.append((f"runs row {row['key']} fit", json.loads(row["json"])["fit"], row["json"].encode()))
    return out


RECORDED = _recorded_fits()


def test_the_recording_holds_node_pair_run_and_stored_fits() -> None:
    kinds = {where.split(" ")[0] for where, _fit, _frame in RECORDED}
    assert {"calib", "calib.get", "run", "fits", "runs"} <= kinds
    assert any("groups.DDR_AB" in where for where, _fit, _frame in RECORDED)
    assert any(fit.get("trust") for _where, fit, _frame in RECORDED)


@pytest.mark.parametrize(("where", "fit", "frame"), RECORDED, ids=[w for w, _f, _b in RECORDED])
def test_a_recorded_fit_reads_and_writes_back_to_the_same_bytes(where: str, fit: dict[str, Any],
                                                                 frame: bytes) -> None:
    record = FitRecord.from_dict(fit, strict=True)
    written = dumps(record.to_dict())
    assert written == dumps(fit)
    assert written in frame  # the very bytes the daemon sent or stored
    assert tuple(record.keys) == FIT_FIELDS and record.currents and record.n_runs is not None


def test_the_typed_fields_are_the_recorded_numbers() -> None:
    """Each current's value, interval, verdict and the errors are the JSON's, not defaults."""
    _where, fit, _frame = next(r for r in RECORDED if r[0].startswith("fits row"))
    record = FitRecord.from_dict(fit)
    for name, entry in fit["currents"].items():
        current = record.currents[name]
        assert current.calibrated_a == entry["calibrated"] and list(current.ci95_a) == entry["ci95"]
        assert current.identifiable is entry["identifiable"] and current.datasheet_a == entry["datasheet"]
    assert (record.error.before, record.error.after) == (fit["error"]["before"], fit["error"]["after"])
    assert record.commands == fit["trust"]["commands"] == "counted"


def test_a_runs_list_summary_reads_and_writes_back() -> None:
    """The summary of a run's fit (``run_summary``) keeps only ``n_runs`` and ``error.after``."""
    _where, fit, _frame = next(r for r in RECORDED if r[0].startswith("runs row"))
    summary = run_summary({"run_id": "r1", "state": "done", "fit": fit})["fit"]
    record = FitRecord.from_dict(summary)
    assert dumps(record.to_dict()) == dumps(summary)
    assert record.n_runs == fit["n_runs"] and record.error.after == fit["error"]["after"]
    assert math.isnan(record.error.loo) and record.currents == {} and record.problems == ()


def test_missing_and_ill_typed_fields_are_unknown_and_named_never_zero() -> None:
    record = FitRecord.from_dict({"currents": {"idd0": {"calibrated": "0.05", "ci95": [0.01], "identifiable": 1},
                                               "idd3n": 7},
                                  "error": {"after": None, "loo": "x"}, "dof": 2.5, "status": 3})
    idd0 = record.currents["idd0"]
    assert math.isnan(idd0.calibrated_a) and math.isnan(idd0.half_width_a)
    assert idd0.identifiable is None and idd0.verdict == "unknown"
    assert record.currents["idd3n"] == CurrentFit("idd3n")
    assert record.n_runs is None and record.dof is None and record.status is None
    assert math.isnan(record.error.after) and math.isnan(record.error.loo)
    assert not record.determined  # unknown runs and dof: not "more runs than unknowns"
    assert record.problems == (
        "n_runs: missing",
        "currents.idd0.calibrated = '0.05': expected a number",
        "currents.idd0.ci95 = '[0.01]': expected [low, high]",
        "currents.idd0.identifiable = '1': expected true or false",
        "currents.idd3n = '7': expected an object",
        "error.loo = 'x': expected a number",
        "dof = '2.5': expected an integer",
        "status = '3': expected a string",
    )
    with pytest.raises(ValueError, match=r"currents\.idd3n = '7': expected an object"):
        FitRecord.from_dict(record.to_dict() | {"currents": {"idd3n": 7}}, strict=True)
    with pytest.raises(ValueError, match="not a fit record: list"):
        FitRecord.from_dict([1, 2])  # type: ignore[arg-type]


def test_a_held_current_is_held_not_determined() -> None:
    """``trust.held`` names currents held at a value the runs cannot see: their verdict says so."""
    fit = {"n_runs": 9, "error": {}, "currents": {"idd2p": {"calibrated": 0.02, "ci95": [0.01, 0.03],
                                                             "identifiable": False}},
           "trust": {"commands": "modelled", "held": {"idd2p": {"value": 0.02, "anchor": "idd2n"}}}}
    record = FitRecord.from_dict(fit)
    assert record.currents["idd2p"].verdict == "held" and record.commands == "modelled"


def test_the_store_check_quarantines_an_ill_typed_fit_and_names_the_field() -> None:
    _where, fit, _frame = next(r for r in RECORDED if r[0].startswith("fits row"))
    check_fit(fit)
    damaged = json.loads(json.dumps(fit))
    damaged["currents"]["idd0"]["ci95"] = "wide"
    with pytest.raises(ValueError, match=r"currents.idd0.ci95 = 'wide': expected \[low, high\]"):
        check_fit(damaged)


def test_the_tui_shows_an_ill_typed_current_as_unknown_not_zero() -> None:
    """An ill-typed current is unknown (NaN) in the calibration panel; the fields beside it show as sent."""
    view = calib_view({"fit": {"n_runs": 3, "error": {"after": 0.1},
                               "currents": {"idd0": {"datasheet": 0.06, "calibrated": "x", "ci95": "wide"}}}})
    (idd0,) = view.currents
    assert math.isnan(idd0.calibrated_a) and math.isnan(idd0.ci95_a) and idd0.datasheet_a == 0.06
    assert view.n_runs == 3 and view.error_after == 0.1 and math.isnan(view.error_loo)
