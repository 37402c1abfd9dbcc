"""Counts on the command line, spelled the way users write them: ``100000000``, ``1e8``, ``2**27``,
``1_000_000``.

``bench --elements`` and ``model kernel --elements`` take the same spellings, so a size copied from
one command works in the other.

Example:
    >>> whole_number("2**20"), whole_number("1e6"), whole_number("1_000")
    (1048576, 1000000, 1000)
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

#: How the accepted spellings are described in messages.
SPELLINGS = "e.g. 100000000, 1e8 or 2**27"
#: ``B**E`` larger than this many bits is refused before it is computed.
MAX_BITS = 128


def whole_number(text: str) -> int:
    """``text`` as a whole number: digits, scientific notation with an integral value, or ``B**E``.

    Raises:
        ValueError: anything else (a fraction, NaN, infinity, garbage), with a message naming it.
    """
    raw = text.strip().replace("_", "")
    try:
        if "**" in raw:
            base, exp = (int(part) for part in raw.split("**", 1))
            if exp < 0 or (abs(base) > 1 and exp * math.log2(abs(base)) > MAX_BITS):
                raise ValueError  # a fraction, or a number no machine has memory for
            return int(base ** exp)
        try:
            return int(raw)
        except ValueError:
            number = float(raw)
            if not math.isfinite(number) or number != int(number):
                raise ValueError from None
            return int(number)
    except (ValueError, OverflowError):
        raise ValueError(f"{text!r} is not a whole number; expected {SPELLINGS}") from None


def count_at_least(minimum: int, unit: str = "") -> Callable[[str], int]:
    """An argparse ``type``: a :func:`whole_number` of at least ``minimum`` (``unit`` names what
    is counted in the message, e.g. ``"doubles (one 64-byte line)"``).

    Example:
        >>> count_at_least(1)("0")
        Traceback (most recent call last):
        ...
        argparse.ArgumentTypeError: 0 is too small; expected at least 1
    """
    what = f" {unit}" if unit else ""

    def parse(text: str) -> int:
        try:
            value = whole_number(text)
        except ValueError as error:
            raise argparse.ArgumentTypeError(str(error)) from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"{value} is too small; expected at least {minimum}{what}")
        return value

    parse.__name__ = "count"  # argparse names the type in its own messages
    return parse


def counted(n: object, noun: str) -> str:
    """``n`` and ``noun`` in the right number ("1 run", "3 runs", "0 runs"; unknown: "– runs").

    Example:
        >>> counted(1, "run"), counted(28, "run"), counted(None, "run")
        ('1 run', '28 runs', '– runs')
    """
    if isinstance(n, bool) or not isinstance(n, int):
        return f"– {noun}s"
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"
