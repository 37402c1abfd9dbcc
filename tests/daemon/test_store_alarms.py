"""Calibration alarms in the state database: appended through the store's writer, read back after a
reopen, and a database made before the alarms table gains it."""

from __future__ import annotations

import sqlite3
from pathlib import Path

from hdeem_watch.daemon.store.database import Store

ALARM = {"group": "DDR_CD", "current": "energy", "kind": "residual-cusum", "statistic": 12.4, "threshold": 12.0,
         "time_ns": 7, "direction": "up"}


def test_alarms_are_stored_and_read_back(tmp_path: Path) -> None:
    store = Store(tmp_path / "state.db")
    try:
        store.save_alarm(7, "r3", ALARM)
        store.save_alarm(9, "r5", {**ALARM, "group": "DDR_AB", "time_ns": 9})
        assert [a["alarm"]["group"] for a in store.list_alarms()] == ["DDR_CD", "DDR_AB"]
    finally:
        store.close()
    again = Store(tmp_path / "state.db")
    try:
        stored = again.list_alarms()
        assert stored == [{"t_ns": 7, "run_id": "r3", "alarm": ALARM},
                          {"t_ns": 9, "run_id": "r5", "alarm": {**ALARM, "group": "DDR_AB", "time_ns": 9}}]
        assert [a["run_id"] for a in again.list_alarms(1)] == ["r5"]
    finally:
        again.close()


def test_a_database_without_the_alarms_table_gains_it(tmp_path: Path) -> None:
    path = tmp_path / "state.db"
    Store(path).close()
    with sqlite3.connect(path) as db:
        db.execute("DROP TABLE alarms")
    store = Store(path)
    try:
        store.save_alarm(1, None, ALARM)
        assert store.list_alarms() == [{"t_ns": 1, "run_id": None, "alarm": ALARM}]
    finally:
        store.close()
