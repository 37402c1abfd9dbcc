"""The tolerant field reader under the typed records' parsers (fits and jobs).

A record's parser reads each field through :class:`FieldReader`: a value of the expected type is
returned, null or an absent key is unknown (None; NaN for :meth:`FieldReader.real`), and a value
of the wrong type is unknown too and named in :attr:`FieldReader.problems` — never taken as 0.

Example:
    >>> reader = FieldReader({"n": 3, "x": "high"}, required=("n", "t"))
    >>> reader.integer("n"), reader.real("x"), reader.problems
    (3, nan, ['t: missing', "x = 'high': expected a number"])
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from typing import Any

__all__ = ["FieldReader", "is_number"]


def is_number(value: Any) -> bool:
    """A JSON number (not a bool)."""
    return isinstance(value, int | float) and not isinstance(value, bool)


class FieldReader:
    """Reads the fields of one JSON object, collecting what it could not read.

    Args:
        data: the object.
        required: keys whose absence is a problem (any other absent key is just unknown).
        prefix: put before every key named in a problem (a nested object's path, ``"error."``).
        problems: the list to add problems to (a nested object's reader shares its parent's).
    """

    def __init__(self, data: Mapping[str, Any], *, required: Iterable[str] = (), prefix: str = "",
                 problems: list[str] | None = None) -> None:
        self.data = data
        self.prefix = prefix
        self.problems: list[str] = problems if problems is not None else []
        self.problems.extend(f"{prefix}{key}: missing" for key in required if key not in data)

    def value(self, key: str, ok: Callable[[Any], bool], expected: str) -> Any:
        """The value of ``key`` if ``ok`` accepts it; else None (a non-null one is named)."""
        value = self.data.get(key)
        if value is None:
            return None
        if ok(value):
            return value
        self.problems.append(f"{self.prefix}{key} = {str(value)[:40]!r}: expected {expected}")
        return None

    def text(self, key: str) -> str | None:
        value = self.value(key, lambda v: isinstance(v, str), "a string")
        return None if value is None else str(value)

    def integer(self, key: str) -> int | None:
        value = self.value(key, lambda v: isinstance(v, int) and not isinstance(v, bool), "an integer")
        return None if value is None else int(value)

    def optional_real(self, key: str) -> float | None:
        value = self.value(key, is_number, "a number")
        return None if value is None else float(value)

    def real(self, key: str) -> float:
        value = self.optional_real(key)
        return math.nan if value is None else value

    def mapping(self, key: str) -> dict[str, Any] | None:
        value = self.value(key, lambda v: isinstance(v, Mapping), "an object")
        return None if value is None else dict(value)

    def array(self, key: str) -> list[Any] | None:
        value = self.value(key, lambda v: isinstance(v, list), "a list")
        return None if value is None else list(value)
