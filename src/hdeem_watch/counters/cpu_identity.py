"""CPU identity from ``/proc/cpuinfo`` and the IMC counter generation it belongs to.

The generation decides the event encodings (:mod:`hdeem_watch.counters.event_tables`). The model
numbers are those of Intel's perfmon ``mapfile.csv`` (github.com/intel/perfmon), which also picks the
event file per CPU: ``GenuineIntel-6-3F`` Haswell-EP, ``6-4F`` Broadwell-EP, ``6-55`` stepping 0-4
Skylake-SP and 5-F Cascade Lake-SP, ``6-6A``/``6-6C`` Ice Lake-SP, ``6-8F`` Sapphire Rapids. AMD's are
the Linux perf tool's ``tools/perf/pmu-events/arch/x86/mapfile.csv``: ``AuthenticAMD-25-…`` is Zen 4
except models 00-0F and 20-5F (Zen 3, whose UMC has no perf PMU), ``AuthenticAMD-26-…`` models 00-2F,
40-4F and 60-7F Zen 5.

Example:
    >>> ident = parse_cpuinfo("vendor_id : GenuineIntel\\ncpu family : 6\\nmodel : 63\\nstepping : 2\\n")
    >>> generation_of(ident)
    'haswell-ep'
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from hdeem_watch.errors import InputError

DEFAULT_CPUINFO = "/proc/cpuinfo"

#: ``(family, model)`` → generation, where the stepping does not matter.
_BY_MODEL = {
    (6, 0x3F): "haswell-ep",
    (6, 0x4F): "broadwell-ep",
    (6, 0x6A): "ice-lake-sp",
    (6, 0x6C): "ice-lake-sp",
    (6, 0x8F): "sapphire-rapids",
}
#: Family 6 model 0x55 is Skylake-SP for steppings 0-4 and Cascade Lake-SP from stepping 5 (mapfile.csv).
_MODEL_SKX_CLX = 0x55
_FIRST_CLX_STEPPING = 5


@dataclass(frozen=True)
class CpuIdentity:
    """The first processor entry of ``/proc/cpuinfo``.

    Attributes:
        vendor: ``vendor_id`` (``GenuineIntel``, ``AuthenticAMD``, ...).
        family: ``cpu family``.
        model: ``model`` (decimal in cpuinfo).
        stepping: ``stepping`` (-1 when absent, as on some virtual CPUs).
        model_name: ``model name`` ("" when absent).
    """

    vendor: str
    family: int
    model: int
    stepping: int
    model_name: str

    def signature(self) -> str:
        """perfmon's form, e.g. ``GenuineIntel-6-3F``."""
        return f"{self.vendor}-{self.family}-{self.model:X}"


def parse_cpuinfo(text: str, where: str = "cpuinfo") -> CpuIdentity:
    """Read the first processor's identity from ``/proc/cpuinfo`` text.

    Raises:
        InputError: naming ``where`` when ``vendor_id``, ``cpu family`` or ``model`` is missing or
            not a number.
    """
    first: dict[str, str] = {}
    for line in text.splitlines():
        if not line.strip():
            if first:
                break
            continue
        key, sep, value = line.partition(":")
        if sep:
            first.setdefault(key.strip(), value.strip())
    missing = [k for k in ("vendor_id", "cpu family", "model") if k not in first]
    if missing:
        raise InputError(f"{where}: no {', '.join(repr(m) for m in missing)} line; expected /proc/cpuinfo text")

    def number(key: str, default: int | None = None) -> int:
        raw = first.get(key)
        if raw is None and default is not None:
            return default
        try:
            return int(str(raw), 0) if str(raw).startswith("0x") else int(str(raw))
        except ValueError:
            raise InputError(f"{where}: {key} = {raw!r} is not a number") from None

    return CpuIdentity(vendor=first["vendor_id"], family=number("cpu family"), model=number("model"),
                       stepping=number("stepping", -1), model_name=first.get("model name", ""))


def read_cpuinfo(path: str | Path = DEFAULT_CPUINFO) -> CpuIdentity:
    """:func:`parse_cpuinfo` of a file.

    Raises:
        InputError: the file cannot be read or has no identity lines.
    """
    try:
        text = Path(path).read_text()
    except OSError as error:
        raise InputError(f"{path}: cannot read ({error.strerror})") from None
    return parse_cpuinfo(text, where=str(path))


def _amd_generation(family: int, model: int) -> str | None:
    """``zen4``/``zen5`` by perf's mapfile.csv rows (Zen 3 and unknown families: ``None``)."""
    if family == 25 and not (model < 0x10 or 0x20 <= model < 0x60):
        return "zen4"
    if family == 26 and (model < 0x30 or 0x40 <= model < 0x50 or 0x60 <= model < 0x80):
        return "zen5"
    return None


def generation_of(identity: CpuIdentity) -> str | None:
    """The memory-controller counter generation of a CPU, or ``None`` when no event table covers it."""
    if identity.vendor == "AuthenticAMD":
        return _amd_generation(identity.family, identity.model)
    if identity.vendor != "GenuineIntel":
        return None
    if (identity.family, identity.model) == (6, _MODEL_SKX_CLX):
        return "cascade-lake-sp" if identity.stepping >= _FIRST_CLX_STEPPING else "skylake-sp"
    return _BY_MODEL.get((identity.family, identity.model))
