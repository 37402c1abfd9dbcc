"""A detected fact and where it came from; unknown is ``None`` with the reason as its source.

Example:
    >>> Fact(2, "sysfs: cpu/*/topology/physical_package_id").value
    2
    >>> Fact.unknown("EDAC not loaded").known
    False
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Generic, TypeVar

T = TypeVar("T")


@dataclass(frozen=True)
class Fact(Generic[T]):
    """One fact about the node.

    Attributes:
        value: the value, ``None`` when it could not be detected.
        source: where the value came from (``"sysfs: ..."``, ``"edac: ..."``, ``"dmidecode: ..."``,
            ``"config [node]"``, ``"default: ..."``), or why it is unknown.
    """

    value: T | None
    source: str

    @property
    def known(self) -> bool:
        """Whether a value was found."""
        return self.value is not None

    @classmethod
    def unknown(cls, why: str) -> Fact[T]:
        """An undetected fact with the reason."""
        return cls(None, f"unknown: {why}")

    def or_else(self, other: Fact[T]) -> Fact[T]:
        """This fact if known, else ``other``."""
        return self if self.known else other

    def to_json(self) -> dict[str, object]:
        """``{"value": ..., "source": ...}``."""
        return {"value": self.value, "source": self.source}
