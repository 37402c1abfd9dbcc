"""PMU ``format/`` fields: parse the kernel's bit-field descriptions and encode events with them.

Each file under ``/sys/bus/event_source/devices/<pmu>/format/`` names one field of an event and
holds where its bits go, e.g. ``config:0-7`` or ``config:8-15,32-55`` (Linux
``Documentation/ABI/testing/sysfs-bus-event_source-devices-format``: ``<config word>:<bit or
range>[,<bit or range>...]``; the value's low bits fill the first range, the next bits the next
range). The uncore driver defines the IMC fields in ``arch/x86/events/intel/uncore_snbep.c``
(``DEFINE_UNCORE_FORMAT_ATTR(event, event, "config:0-7")``, ``umask "config:8-15"``, ...).

Example:
    >>> fields = {"event": parse_format("config:0-7"), "umask": parse_format("config:8-15")}
    >>> hex(encode_event(fields, {"event": 0x04, "umask": 0x03})["config"])
    '0x304'
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass

from hdeem_watch.errors import InputError

#: The ``perf_event_attr`` words a format field may target.
CONFIG_WORDS = ("config", "config1", "config2", "config3")

_SPEC = re.compile(r"^(config[123]?):([0-9,\-]+)$")


@dataclass(frozen=True)
class FormatField:
    """Where one event field's bits go.

    Attributes:
        word: the ``perf_event_attr`` word (``config``, ``config1``, ...).
        ranges: inclusive ``(low, high)`` bit ranges, in the order the value's bits fill them.
    """

    word: str
    ranges: tuple[tuple[int, int], ...]

    @property
    def width(self) -> int:
        """Number of bits of the field."""
        return sum(high - low + 1 for low, high in self.ranges)

    def place(self, value: int) -> int:
        """``value`` spread over this field's bit ranges (the word's other bits are 0).

        Raises:
            InputError: ``value`` is negative or does not fit in :attr:`width` bits.
        """
        if value < 0 or value >> self.width:
            raise InputError(f"value {value:#x} does not fit the {self.width}-bit field {self.describe()}")
        placed = 0
        for low, high in self.ranges:
            size = high - low + 1
            placed |= (value & ((1 << size) - 1)) << low
            value >>= size
        return placed

    def describe(self) -> str:
        """The sysfs form, e.g. ``config:8-15,32-55``."""
        parts = [f"{lo}" if lo == hi else f"{lo}-{hi}" for lo, hi in self.ranges]
        return f"{self.word}:{','.join(parts)}"


def parse_format(text: str, where: str = "format") -> FormatField:
    """Parse one sysfs format file's content (``config:0-7``, ``config1:1,6-10,44``).

    Raises:
        InputError: naming ``where`` and the text when it is not of that form.
    """
    spec = text.strip()
    match = _SPEC.match(spec)
    if not match:
        raise InputError(f"{where}: {spec!r} is not a format field like 'config:0-7' or 'config:8-15,32-55'")
    ranges = []
    for part in match.group(2).split(","):
        bounds = part.split("-")
        if len(bounds) > 2 or not all(b.isdigit() for b in bounds):
            raise InputError(f"{where}: {spec!r}: bad bit range {part!r}")
        low, high = int(bounds[0]), int(bounds[-1])
        if not low <= high <= 63:
            raise InputError(f"{where}: {spec!r}: bit range {part!r} is not within 0-63 in increasing order")
        ranges.append((low, high))
    return FormatField(word=match.group(1), ranges=tuple(ranges))


def encode_event(fields: Mapping[str, FormatField], values: Mapping[str, int]) -> dict[str, int]:
    """The ``perf_event_attr`` words for an event given as field values (``event=0x04, umask=0x03``).

    Returns:
        ``{"config": ..., "config1": ..., ...}`` with every word of :data:`CONFIG_WORDS` (0 when unused).

    Raises:
        InputError: a field the PMU does not define, or a value that does not fit its field.
    """
    words = dict.fromkeys(CONFIG_WORDS, 0)
    for name, value in values.items():
        field = fields.get(name)
        if field is None:
            raise InputError(f"the PMU has no format field {name!r}; it defines {sorted(fields)}")
        words[field.word] |= field.place(value)
    return words
