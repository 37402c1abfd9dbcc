"""docs/architecture.md's package table matches the tree (issue #26) for the packages it was redrawn
for: every module of ``daemon/`` (its sub-packages included), ``calibrate/`` and ``sim/`` has its row, and no
row names a module that is not there."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "hdeem_watch"
#: The packages whose rows must list exactly their modules.
CHECKED = ("daemon", "calibrate", "sim")


def table_modules(text: str) -> set[str]:
    """``package/module.py`` for every module the table's rows name (a row with an empty package
    cell continues the package above it)."""
    listed: set[str] = set()
    package = ""
    for line in text.splitlines():
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
        if not line.startswith("|") or len(cells) < 3 or cells[0] in ("package", "---"):
            continue
        if cells[0]:
            package = cells[0].strip("`").rstrip("/")
        listed.update(f"{package}/{name}" for name in re.findall(r"`([a-z_0-9]+\.py)`", cells[1]))
    return listed


def test_the_table_reader_follows_continued_rows() -> None:
    text = "| package | modules | what |\n|---|---|---|\n| `a/` | `x.py`, `y.py` | . |\n| | `z.py` | . |\n"
    assert table_modules(text) == {"a/x.py", "a/y.py", "a/z.py"}


def test_every_daemon_and_calibrate_module_is_in_the_table_and_no_other() -> None:
    listed = {name for name in table_modules((ROOT / "docs" / "architecture.md").read_text(encoding="utf-8"))
              if name.split("/")[0] in CHECKED}
    present = {path.relative_to(PACKAGE).as_posix() for package in CHECKED
               for path in (PACKAGE / package).rglob("*.py") if path.name != "__init__.py"}
    assert not present - listed, f"add to docs/architecture.md's table: {sorted(present - listed)}"
    assert not listed - present, f"not in the tree: {sorted(listed - present)}"
