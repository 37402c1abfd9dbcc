"""Aging of the simulated node's DIMM pairs: ``--sim-age DDR_CD=+30%/h`` and the factor it puts on currents.

A pair that ages draws more current over time: every true current of its DIMMs is multiplied by
``1 + rate × max(0, t − start)`` (``rate`` per sim second, linear in sim time, so ``--speed 60``
makes an hour pass in a minute). The CLI form is ``PAIR=±X%/h`` (also ``%/min``, ``%/s``), several
separated by commas, optionally with a start ``@<seconds>s`` or ``@<minutes>min``:
``DDR_CD=+30%/h@600s`` starts the drift ten sim-minutes after the sim opens.

Example:
    >>> parse_sim_age("DDR_CD=+30%/h")
    {'DDR_CD': 0.3}
    >>> parse_sim_age_start("DDR_CD=+30%/h@10min")
    {'DDR_CD': 600.0}
    >>> round(age_factor(0.3, 0.0, 1800.0), 6)
    1.15
    >>> sim_age_options("DDR_CD=+30%/h@10min")
    {'age': {'DDR_CD': 0.3}, 'age_start_s': {'DDR_CD': 600.0}}
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping

from hdeem_watch.errors import InputError

_SECONDS = {"h": 3600.0, "min": 60.0, "s": 1.0}
_ITEM = re.compile(r"^\s*(?P<pair>[A-Za-z][A-Za-z0-9_]*)\s*=\s*(?P<value>[+-]?\d+(?:\.\d*)?|[+-]?\.\d+)\s*%\s*/\s*"
                   r"(?P<per>h|min|s)\s*(?:@\s*(?P<start>\d+(?:\.\d*)?)\s*(?P<start_unit>s|min|h))?\s*$")
_EXPECTED = "expected PAIR=±X%/h (or %/min, %/s), optionally @<start>s|min|h, comma-separated, e.g. DDR_CD=+30%/h"


def _items(text: str) -> list[re.Match[str]]:
    if not isinstance(text, str) or not text.strip():
        raise InputError(f"--sim-age {text!r}: empty; {_EXPECTED}")
    out = []
    seen: set[str] = set()
    for part in text.split(","):
        match = _ITEM.match(part)
        if match is None:
            raise InputError(f"--sim-age {part.strip()!r}: {_EXPECTED}")
        pair = match["pair"].upper()
        if pair in seen:
            raise InputError(f"--sim-age {text!r}: pair {pair} given twice")
        seen.add(pair)
        out.append(match)
    return out


def parse_sim_age(text: str) -> dict[str, float]:
    """The aging rates of ``--sim-age`` as ``{pair: relative growth per sim hour}``.

    Args:
        text: e.g. ``"DDR_CD=+30%/h"`` or ``"DDR_AB=+0.5%/min,DDR_GH=-10%/h"``.

    Raises:
        InputError: one line naming the bad item and the expected form.
    """
    rates = {}
    for match in _items(text):
        per_h = float(match["value"]) / 100.0 * 3600.0 / _SECONDS[match["per"]]
        if not math.isfinite(per_h):
            raise InputError(f"--sim-age {match.group(0).strip()!r}: not a finite rate; {_EXPECTED}")
        rates[match["pair"].upper()] = per_h
    return rates


def parse_sim_age_start(text: str) -> dict[str, float]:
    """The start of each pair's drift in ``--sim-age`` (sim seconds since open; 0 without ``@``)."""
    return {match["pair"].upper(): float(match["start"]) * _SECONDS[match["start_unit"]] if match["start"] else 0.0
            for match in _items(text)}


def sim_age_options(text: str | None) -> dict[str, dict[str, float]]:
    """``SimSource`` keyword options of a ``--sim-age`` value (``{}`` for None or empty).

    Raises:
        InputError: as :func:`parse_sim_age`.
    """
    if text is None or not str(text).strip():
        return {}
    return {"age": parse_sim_age(text), "age_start_s": parse_sim_age_start(text)}


def check_pairs(age: Mapping[str, float], pairs: Iterable[str]) -> dict[str, float]:
    """``age`` with upper-case pair names, every one a DRAM sensor of the node.

    Raises:
        InputError: a pair the node does not have, or a rate that is not a finite number.
    """
    known = tuple(pairs)
    out = {}
    for pair, rate in age.items():
        name = str(pair).upper()
        if name not in known:
            raise InputError(f"sim age: pair {pair!r} is not a DRAM sensor of this node; expected one of "
                             f"{', '.join(known)}")
        if isinstance(rate, bool) or not isinstance(rate, int | float) or not math.isfinite(rate):
            raise InputError(f"sim age: {name} = {rate!r}; expected a finite relative rate per hour (0.30 = +30 %/h)")
        out[name] = float(rate)
    return out


def age_factor(rate_per_h: float, start_s: float, t_s: float) -> float:
    """The factor on a pair's currents at sim time ``t_s``: ``1 + rate × hours since start`` (never below 0.05)."""
    hours = max(0.0, float(t_s) - float(start_s)) / 3600.0
    return max(0.05, 1.0 + float(rate_per_h) * hours)
