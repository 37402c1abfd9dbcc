"""One figure of a report: the matplotlib figure, what it shows, how to read it, and its numbers.

Example:
    >>> table = Table(("kernel", "energy J"), (("triad", 1.5),))
    >>> table.csv().splitlines()
    ['kernel,energy J', 'triad,1.5']
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Table:
    """The numbers a figure shows: a header and rows (NaN/None = unknown, shown as "–")."""

    columns: tuple[str, ...]
    rows: tuple[tuple[Any, ...], ...]

    def csv(self) -> str:
        """The table as CSV text (unknown = empty cell)."""
        out = io.StringIO()
        writer = csv.writer(out, lineterminator="\n")
        writer.writerow(self.columns)
        for row in self.rows:
            writer.writerow(["" if _unknown(v) else v for v in row])
        return out.getvalue()


@dataclass(frozen=True)
class ReportFigure:
    """A drawn figure.

    Attributes:
        key: file stem (``fig1-energy``).
        title: heading on the page.
        how_to_read: one sentence under the heading.
        figure: the matplotlib figure.
        tables: the numbers behind it, by caption.
        missing: what has no data (empty = everything was drawn).
        notes: caveats about what is drawn (e.g. how far a re-modelled split is from the daemon's rows).
    """

    key: str
    title: str
    how_to_read: str
    figure: Any
    tables: dict[str, Table] = field(default_factory=dict)
    missing: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()


def fmt(value: Any, digits: int = 4) -> str:
    """A cell as text: numbers to ``digits`` significant digits, unknown as "–"."""
    if _unknown(value):
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.{digits}g}"
    return str(value)


def _unknown(value: Any) -> bool:
    return value is None or (isinstance(value, float) and not math.isfinite(value))


def rows(items: Sequence[Sequence[Any]]) -> tuple[tuple[Any, ...], ...]:
    """Rows as a tuple of tuples (for :class:`Table`)."""
    return tuple(tuple(row) for row in items)
