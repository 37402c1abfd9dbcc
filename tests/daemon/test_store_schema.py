"""The state database's schema has one owner: the store writes what it declares, the report reads by it."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

from hdeem_watch import state_schema as store_schema
from hdeem_watch.daemon.store.database import Store


def test_the_store_creates_exactly_the_tables_and_columns_the_owner_declares(tmp_path: Path) -> None:
    store = Store(tmp_path / "state.db")
    store.close()
    db = sqlite3.connect(tmp_path / "state.db")
    found = store_schema.table_columns(db)
    assert store_schema.schema_version(db) == store_schema.SCHEMA_VERSION
    db.close()
    assert {name: tuple(columns) for name, columns in found.items() if name != "sqlite_sequence"} == \
        {name: table.columns for name, table in store_schema.TABLES.items()}


def test_every_table_has_its_key_and_json_column_among_its_columns() -> None:
    for name, table in store_schema.TABLES.items():
        assert table.key in table.columns, name
        assert table.json is None or table.json in table.columns, name


def test_a_garbled_version_is_refused_not_guessed() -> None:
    db = sqlite3.connect(":memory:")
    db.executescript(store_schema.SCHEMA)
    db.execute("INSERT INTO meta VALUES ('schema_version', 'one')")
    with pytest.raises(ValueError, match="'one' is not a version number"):
        store_schema.schema_version(db)
    assert store_schema.has_every_table(db)
