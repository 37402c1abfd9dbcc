"""Field checks shared by the DDR4 and DDR5 memspec readers (DRAMPower's JSON).

Each check names the file, the field and what was expected in one line (``InputError``); the
plausibility limits catch a unit typed wrong (mA for A, mV for V, ns for s). The readers
(:mod:`hdeem_watch.dram.memspec`, :mod:`hdeem_watch.dram.memspec_ddr5`) know their standard's
fields; these functions know how one field is spelt and checked.

Example:
    >>> int_field({"RAS": 32}, "RAS", "f.json: memspec.memtimingspec", positive=True)
    32
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from hdeem_watch.errors import InputError

#: A per-device current above this is almost surely milliamperes typed as amperes.
MAX_DEVICE_CURRENT_A = 1.0
#: A supply voltage above this is almost surely millivolts.
MAX_VOLTAGE_V = 5.0
#: A clock period above this is almost surely nanoseconds typed as seconds.
MAX_TCK_S = 1e-6


def is_number(value: Any) -> bool:
    """An int or float (not a bool)."""
    return isinstance(value, int | float) and not isinstance(value, bool)


def check_current(where: str, value: Any) -> float:
    """``value`` as a current in amperes per device (finite, >= 0, not milliamperes)."""
    if not is_number(value) or not math.isfinite(value):
        raise InputError(f"{where} = {value!r}: not a number; expected a current in amperes")
    if value < 0:
        raise InputError(f"{where} = {value!r}: negative; expected a current >= 0 A")
    if value > MAX_DEVICE_CURRENT_A:
        raise InputError(f"{where} = {value!r} looks like mA; expected amperes per device ({value / 1000:g})")
    return float(value)


def section(spec: Mapping[str, Any], name: str, where: str) -> Mapping[str, Any]:
    """The object ``memspec.<name>``."""
    found = spec.get(name)
    if found is None:
        raise InputError(f"{where}: memspec.{name}: missing section")
    if not isinstance(found, Mapping):
        raise InputError(f"{where}: memspec.{name}: expected an object, got {type(found).__name__}")
    return found


def int_field(fields: Mapping[str, Any], key: str, where: str, *, positive: bool) -> int:
    """``fields[key]`` as a non-negative (``positive``: > 0) integer."""
    if key not in fields:
        raise InputError(f"{where}: missing field {key}")
    value = fields[key]
    if not is_number(value) or not math.isfinite(value) or value != int(value):
        raise InputError(f"{where}.{key} = {value!r}: expected an integer")
    if value < 0 or (positive and value == 0):
        raise InputError(f"{where}.{key} = {value!r}: expected a {'positive' if positive else 'non-negative'} integer")
    return int(value)


def header(spec: Any, where: str, memory_type: str) -> tuple[str, str]:
    """(``memoryType``, ``memoryId``) of a memspec object of the standard ``memory_type``."""
    if not isinstance(spec, Mapping):
        raise InputError(f"{where}: expected a JSON object with a 'memspec' object")
    found = spec.get("memoryType")
    if not isinstance(found, str) or found.upper() != memory_type:
        raise InputError(f"{where}: memspec.memoryType = {found!r}; expected '{memory_type}'")
    memory_id = spec.get("memoryId", "")
    if not isinstance(memory_id, str):
        raise InputError(f"{where}: memspec.memoryId = {memory_id!r}: expected a string")
    return found, memory_id


def timings(spec: Mapping[str, Any], where: str, required: tuple[str, ...],
            positive: tuple[str, ...] = ()) -> tuple[float, dict[str, int]]:
    """(``tCK`` in seconds, every other memtimingspec field in cycles): the ``required`` ones
    (``positive`` among them > 0) and any extra integer field (kept; a non-integer is an error)."""
    timing = section(spec, "memtimingspec", where)
    at = f"{where}: memspec.memtimingspec"
    if "tCK" not in timing:
        raise InputError(f"{at}: missing field tCK")
    tck = timing["tCK"]
    if not is_number(tck) or not math.isfinite(tck) or tck <= 0:
        raise InputError(f"{at}.tCK = {tck!r}: expected a positive clock period in seconds")
    if tck > MAX_TCK_S:
        raise InputError(f"{at}.tCK = {tck!r} looks like ns; expected seconds ({tck * 1e-9:g})")
    cycles = {key: int_field(timing, key, at, positive=key in positive) for key in required}
    for key in timing:
        if key != "tCK" and key not in cycles:
            cycles[key] = int_field(timing, key, at, positive=False)
    return float(tck), cycles


def voltages(power: Mapping[str, Any], where: str, names: tuple[str, ...]) -> dict[str, float]:
    """The supply voltages ``names`` of mempowerspec in volts (positive, not millivolts)."""
    volts: dict[str, float] = {}
    for key in names:
        if key not in power:
            raise InputError(f"{where}: missing field {key}")
        value = power[key]
        if not is_number(value) or not math.isfinite(value) or value <= 0:
            raise InputError(f"{where}.{key} = {value!r}: expected a positive voltage in volts")
        if value > MAX_VOLTAGE_V:
            raise InputError(f"{where}.{key} = {value!r} looks like mV; expected volts ({value / 1000:g})")
        volts[key] = float(value)
    return volts


def fact_rho(spec: Mapping[str, Any], where: str) -> float:
    """``bankwisespec.factRho`` (1 when absent), a number in [0, 1]."""
    if "bankwisespec" not in spec:
        return 1.0
    bankwise = section(spec, "bankwisespec", where)
    if "factRho" not in bankwise:
        return 1.0
    rho = bankwise["factRho"]
    if not is_number(rho) or not 0.0 <= rho <= 1.0:
        raise InputError(f"{where}: memspec.bankwisespec.factRho = {rho!r}: expected a number in [0, 1]")
    return float(rho)
