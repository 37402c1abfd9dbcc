"""DDR4 memory specifications in DRAMPower's JSON format (read, validate, write back).

A memspec describes one channel: ``nbr_of_ranks`` ranks of ``nbr_of_devices`` identical devices.
Units are SI as in DRAMPower v6: currents in amperes *per device*, voltages in volts, ``tCK`` in
seconds, every other timing in clock cycles.

The file's whole JSON tree is kept, so :meth:`MemSpec.to_json_dict` writes back exactly what was
read (original key spelling, unknown extra sections and fields preserved) with only the values that
were changed (e.g. calibrated currents from :meth:`MemSpec.with_currents`) replaced: the result is a
memspec real DRAMPower reads.

Example:
    >>> spec = preset("ddr4-2133-x8-4gb")
    >>> spec.nbr_of_ranks, spec.nbr_of_devices, spec.timings["RAS"], spec.currents["idd0"]
    (2, 8, 36, 0.0585)
    >>> spec.with_currents({"idd0": 0.04}).to_json_dict()["memspec"]["mempowerspec"]["idd0"]
    0.04
"""

from __future__ import annotations

import copy
import json
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from hdeem_watch.dram import spec_fields as fields
from hdeem_watch.dram.memspec_check import check_physical
from hdeem_watch.dram.spec_fields import MAX_DEVICE_CURRENT_A as MAX_DEVICE_CURRENT_A  # re-exported
from hdeem_watch.errors import InputError

#: memarchitecturespec: JSON key -> attribute (all positive integers).
ARCH_FIELDS: dict[str, str] = {
    "nbrOfChannels": "nbr_of_channels",
    "nbrOfDevices": "nbr_of_devices",
    "nbrOfRanks": "nbr_of_ranks",
    "nbrOfBanks": "nbr_of_banks",
    "nbrOfBankGroups": "nbr_of_bankgroups",
    "nbrOfRows": "nbr_of_rows",
    "nbrOfColumns": "nbr_of_columns",
    "burstLength": "burst_length",
    "dataRate": "data_rate",
    "width": "width",
}
#: Optional memarchitecturespec fields: JSON key -> (attribute, default).
ARCH_OPTIONAL: dict[str, tuple[str, int]] = {"maxBurstLength": ("max_burst_length", 0), "RefMode": ("ref_mode", 1)}

#: memtimingspec fields (cycles, non-negative integers) every DRAMPower DDR4 memspec has.
TIMING_FIELDS: tuple[str, ...] = (
    "CKE", "CKESR", "RAS", "RC", "RCD", "RL", "RPRE", "RTP", "WL", "WPRE", "WR", "XP", "XS", "REFM",
    "REFI", "RFC1", "RFC2", "RFC4", "RP", "DQSCK", "CCD_S", "CCD_L", "FAW", "RRD_S", "RRD_L", "WTR_S",
    "WTR_L", "XPDLL", "XSDLL", "AL", "ACTPDEN", "PRPDEN", "REFPDEN", "RTRS",
)

#: Required currents (JSON spelling) of mempowerspec, amperes per device.
REQUIRED_CURRENTS: tuple[str, ...] = (
    "idd0", "idd2n", "idd3n", "idd4r", "idd4w", "idd5B", "idd6n", "idd2p", "idd3p",
    "ipp0", "ipp2n", "ipp3n", "ipp4r", "ipp4w", "ipp5B", "ipp6n", "ipp2p", "ipp3p",
)
#: Fine-granularity refresh currents: required only when ``RefMode`` selects them, else 0 A.
REFRESH_MODE_CURRENTS: tuple[str, ...] = ("idd5F2", "ipp5F2", "idd5F4", "ipp5F4")
#: Optional bank-wise model currents (default: Iβ = IDD0 resp. IPP0, as in DRAMPower).
BETA_CURRENTS: tuple[str, ...] = ("iBeta_vdd", "iBeta_vpp")
VOLTAGES: tuple[str, ...] = ("vdd", "vpp", "vddq")

@dataclass(frozen=True)
class MemSpec:
    """A validated DDR4 memspec (one channel).

    Attributes:
        memory_id: ``memoryId``.
        memory_type: ``memoryType`` (always ``"DDR4"``).
        nbr_of_channels, nbr_of_devices, nbr_of_ranks, nbr_of_banks, nbr_of_bankgroups,
        nbr_of_rows, nbr_of_columns, burst_length, data_rate, width: memarchitecturespec;
            ``nbr_of_banks`` is per rank, ``nbr_of_devices`` per rank.
        max_burst_length, ref_mode: optional memarchitecturespec fields (0 resp. 1 when absent).
        tck_s: clock period ``tCK`` in seconds.
        timings: every other memtimingspec field, in cycles, JSON key spelling ("RAS", "RFC1", ...).
        currents: amperes per device, keys = mempowerspec keys lower-cased ("idd0", "idd5b",
            "ipp5b", ...; "ibeta_vdd"/"ibeta_vpp" only when the file gives them).
        vdd, vpp, vddq: supply voltages in volts.
        fact_rho: ``bankwisespec.factRho`` (1 when absent).
    """

    memory_id: str
    memory_type: str
    nbr_of_channels: int
    nbr_of_devices: int
    nbr_of_ranks: int
    nbr_of_banks: int
    nbr_of_bankgroups: int
    nbr_of_rows: int
    nbr_of_columns: int
    burst_length: int
    data_rate: int
    width: int
    max_burst_length: int
    ref_mode: int
    tck_s: float
    timings: Mapping[str, int]
    currents: Mapping[str, float]
    vdd: float
    vpp: float
    vddq: float
    fact_rho: float = 1.0
    _raw: Mapping[str, Any] = field(default_factory=dict, repr=False, compare=False)
    _current_keys: Mapping[str, str] = field(default_factory=dict, repr=False, compare=False)

    def __hash__(self) -> int:
        """Hash of every compared field (so specs can key caches); mappings are hashed as sorted items."""
        return hash((self.memory_id, self.nbr_of_devices, self.nbr_of_ranks, self.nbr_of_banks, self.tck_s,
                     tuple(sorted(self.timings.items())), tuple(sorted(self.currents.items())),
                     self.vdd, self.vpp, self.vddq, self.fact_rho, self.ref_mode))

    @property
    def trfc(self) -> int:
        """Refresh cycle time in cycles for the memspec's ``RefMode`` (RFC1, RFC2 or RFC4)."""
        return int(self.timings[{2: "RFC2", 4: "RFC4"}.get(self.ref_mode, "RFC1")])

    @property
    def refresh_currents(self) -> tuple[str, str]:
        """Names of the (VDD, VPP) refresh currents the ``RefMode`` selects, e.g. ("idd5b", "ipp5b")."""
        suffix = {2: "5f2", 4: "5f4"}.get(self.ref_mode, "5b")
        return f"idd{suffix}", f"ipp{suffix}"

    @property
    def burst_cycles(self) -> float:
        """Clock cycles of one burst on the data bus: BL / dataRate."""
        return self.burst_length / self.data_rate

    def with_currents(self, currents: Mapping[str, float]) -> MemSpec:
        """A copy with some currents replaced (e.g. calibrated ones), validated like a file.

        Args:
            currents: amperes per device by lower-case name ("idd0", "ipp5b", "ibeta_vdd", ...).

        Raises:
            InputError: an unknown name or a value that is not a plausible current in amperes.
        """
        known = {key.lower(): key for key in (*REQUIRED_CURRENTS, *REFRESH_MODE_CURRENTS, *BETA_CURRENTS)}
        merged = dict(self.currents)
        keys = dict(self._current_keys)
        for name, value in currents.items():
            lower = name.lower()
            if lower not in known:
                raise InputError(f"with_currents: unknown current {name!r}; expected one of {sorted(known)}")
            merged[lower] = fields.check_current(f"with_currents: {lower}", value)
            keys.setdefault(lower, known[lower])
        return replace(self, currents=merged, _current_keys=keys)

    def to_json_dict(self) -> dict[str, Any]:
        """The DRAMPower JSON tree (``{"memspec": {...}}``) with this spec's values, original spelling."""
        tree = copy.deepcopy(dict(self._raw)) if self._raw else {"memspec": {}}
        spec = tree.setdefault("memspec", {})
        spec["memoryId"] = self.memory_id
        spec["memoryType"] = self.memory_type
        arch = spec.setdefault("memarchitecturespec", {})
        for key, attr in ARCH_FIELDS.items():
            arch[key] = getattr(self, attr)
        for key, (attr, _default) in ARCH_OPTIONAL.items():
            if key in arch or getattr(self, attr) != _default:
                arch[key] = getattr(self, attr)
        timing = spec.setdefault("memtimingspec", {})
        timing["tCK"] = self.tck_s
        for key, value in self.timings.items():
            timing[key] = int(value)
        power = spec.setdefault("mempowerspec", {})
        for key in VOLTAGES:
            power[key] = getattr(self, key)
        for lower, key in self._current_keys.items():
            power[key] = float(self.currents[lower])
        if "bankwisespec" in spec or self.fact_rho != 1.0:
            spec.setdefault("bankwisespec", {})["factRho"] = self.fact_rho
        return tree


def parse_memspec(data: Any, where: str = "memspec", *, allow_unphysical: bool = False) -> MemSpec:
    """Validate a parsed DRAMPower DDR4 memspec JSON tree.

    Args:
        data: the parsed JSON (``{"memspec": {...}}``; a bare inner object is accepted too).
        where: the file name (or other origin) used in error messages.
        allow_unphysical: skip the physical check (:mod:`hdeem_watch.dram.memspec_check`: every
            per-command energy >= 0), e.g. to study a fit's raw output.

    Raises:
        InputError: one line naming ``where``, the field and what was wrong, or the currents that
            make a command's energy negative.
    """
    if isinstance(data, Mapping) and "memspec" in data:
        spec = data["memspec"]
        raw: dict[str, Any] = copy.deepcopy(dict(data))
    else:
        spec = data
        raw = {"memspec": copy.deepcopy(dict(data))} if isinstance(data, Mapping) else {}
    memory_type, memory_id = fields.header(spec, where, "DDR4")
    values = _architecture(spec, where)
    tck, timings = fields.timings(spec, where, TIMING_FIELDS)
    power = fields.section(spec, "mempowerspec", where)
    volts: dict[str, Any] = fields.voltages(power, f"{where}: memspec.mempowerspec", VOLTAGES)
    currents, current_keys = _currents(power, f"{where}: memspec.mempowerspec", values["ref_mode"])
    fact_rho = fields.fact_rho(spec, where)
    for name in ("memimpedancespec", "prepostamble"):
        if name in spec and not isinstance(spec[name], Mapping):
            raise InputError(f"{where}: memspec.{name}: expected an object")
    spec_out = MemSpec(memory_id=memory_id, memory_type=memory_type, tck_s=tck, timings=timings,
                       currents=currents, fact_rho=fact_rho, _raw=raw, _current_keys=current_keys,
                       **volts, **values)
    if not allow_unphysical:
        check_physical(spec_out, where)
    return spec_out


def _architecture(spec: Mapping[str, Any], where: str) -> dict[str, Any]:
    """memarchitecturespec as :class:`MemSpec` attributes (RefMode 1, 2 or 4; banks a multiple of groups)."""
    arch = fields.section(spec, "memarchitecturespec", where)
    at = f"{where}: memspec.memarchitecturespec"
    values: dict[str, Any] = {attr: fields.int_field(arch, key, at, positive=True) for key, attr in ARCH_FIELDS.items()}
    for key, (attr, default) in ARCH_OPTIONAL.items():
        values[attr] = fields.int_field(arch, key, at, positive=True) if key in arch else default
    if values["ref_mode"] not in (1, 2, 4):
        raise InputError(f"{at}.RefMode = {values['ref_mode']!r}: expected 1, 2 or 4")
    if values["nbr_of_banks"] % values["nbr_of_bankgroups"]:
        raise InputError(f"{at}: nbrOfBanks = {values['nbr_of_banks']} is not a multiple of "
                         f"nbrOfBankGroups = {values['nbr_of_bankgroups']}")
    return values


def _currents(power: Mapping[str, Any], where: str, ref_mode: int) -> tuple[dict[str, float], dict[str, str]]:
    """(amperes by lower-case name, the file's spelling of each): the required currents, those of
    the refresh mode (the other modes' are 0 A and not written back) and the optional Iβ."""
    currents: dict[str, float] = {}
    current_keys: dict[str, str] = {}
    mode_currents = {2: ("idd5F2", "ipp5F2"), 4: ("idd5F4", "ipp5F4")}.get(ref_mode, ())
    for key in (*REQUIRED_CURRENTS, *REFRESH_MODE_CURRENTS, *BETA_CURRENTS):
        # accept any capitalisation in the file, remember the file's spelling for writing back
        found = next((k for k in power if k.lower() == key.lower()), None)
        if found is None:
            if key in REQUIRED_CURRENTS or key in mode_currents:
                raise InputError(f"{where}: missing field {key}")
            if key in REFRESH_MODE_CURRENTS:
                currents[key.lower()] = 0.0
            continue
        currents[key.lower()] = fields.check_current(f"{where}.{found}", power[found])
        current_keys[key.lower()] = found
    return currents, current_keys


def load_memspec(path: str | Path, *, allow_unphysical: bool = False) -> MemSpec:
    """Read and validate a DRAMPower DDR4 memspec file.

    Args:
        path: the JSON file.
        allow_unphysical: load currents that give a negative per-command energy (see
            :func:`parse_memspec`).

    Raises:
        InputError: unreadable file, invalid JSON, or an invalid field (named, one line).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as error:
        raise InputError(f"{path}: cannot read memspec: {error.strerror or error}") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a UTF-8 text file; expected a DRAMPower JSON memspec") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as error:
        raise InputError(f"{path}: invalid JSON at line {error.lineno} column {error.colno}: {error.msg}") from None
    return parse_memspec(data, where=str(path), allow_unphysical=allow_unphysical)


def save_memspec(spec: MemSpec, path: str | Path) -> None:
    """Write ``spec`` as a DRAMPower JSON memspec (readable by DRAMPower and :func:`load_memspec`)."""
    Path(path).write_text(json.dumps(spec.to_json_dict(), indent=2) + "\n", encoding="utf-8")


def preset(name: str) -> MemSpec:
    """A built-in memspec by name (see :mod:`hdeem_watch.dram.presets` for the sources of each value).

    Args:
        name: a key of :data:`hdeem_watch.dram.presets.PRESETS`, e.g. ``"samsung-m393a1g43db0-cpb"``.

    Raises:
        InputError: an unknown name.
    """
    from hdeem_watch.dram.presets import PRESETS, preset_path

    if name not in PRESETS:
        raise InputError(f"unknown memspec preset {name!r}; expected one of: {', '.join(sorted(PRESETS))}")
    return load_memspec(preset_path(name))


def memspec_from(value: str | Path, *, allow_unphysical: bool = False) -> MemSpec:
    """A memspec named the way users name one: an existing file, else a preset by that name.

    ``preset:NAME`` always names a preset. A value that is neither an existing file nor a preset
    name is read as a file when it looks like a path (``.json`` or a directory part) and as a preset
    otherwise, so the error names the right thing (the missing file, or the known presets).

    Args:
        value: a file path, or a preset as ``NAME`` or ``preset:NAME``.
        allow_unphysical: load a file whose currents give a negative per-command energy (presets
            are always physical).

    Raises:
        InputError: a missing, malformed or unphysical file, or an unknown preset.
    """
    from hdeem_watch.dram.presets import PRESETS

    text = str(value)
    if text.startswith("preset:"):
        return preset(text.removeprefix("preset:"))
    path = Path(value)
    if path.exists() or (text not in PRESETS and (text.endswith(".json") or len(path.parts) > 1)):
        return load_memspec(path, allow_unphysical=allow_unphysical)
    return preset(text)
