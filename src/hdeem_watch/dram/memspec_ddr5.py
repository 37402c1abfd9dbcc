"""DDR5 memory specifications in DRAMPower's JSON format, read as DRAMPower v6.2 reads them.

The file is DRAMUtils' ``MemSpecDDR5``: ``memspec.memarchitecturespec`` (every field mandatory,
``maxBurstLength`` optional), ``memspec.memtimingspec`` (``tCK`` in seconds, every other timing in
cycles, all mandatory), ``memspec.mempowerspec`` (VDD and VPP currents in amperes *per device*,
``iBeta_vdd``/``iBeta_vpp`` optional), optional ``bankwisespec.factRho``, ``memimpedancespec``
(interface only) and optional ``dataratespec``. ``memoryType`` is ``"DDR5"``.

What the core model uses (DRAMPower v6.2 ``MemSpecDDR5``): ``tCK``, ``RAS``, ``RCD``, ``RTP``,
``WL``, ``WR``, ``RP``; ``RFC1_slr`` with ``idd5b``/``ipp5b`` in refresh mode 1 (``RefMode`` 1, also
the default) or ``RFC2_slr`` with ``idd5f``/``ipp5f`` in mode 2; ``RFCsb_slr`` with
``idd5c``/``ipp5c`` for same-bank refresh; the burst length and data rate of the
memarchitecturespec (``burstLength`` / ``dataRate`` cycles per burst). ``nbrOfDevices`` 0 counts as
1 device, as in DRAMPower. The other timings are required (DRAMPower refuses a file without them)
and kept, but unused by the core.

The whole JSON tree is kept, so :meth:`MemSpecDDR5.to_json_dict` writes back what was read with only
changed currents replaced: a memspec DRAMPower reads.

There are no DDR5 presets: no public DDR5 IDD table with every number the model needs is known to
this project, so the memspec file is the way in (docs/dram-model.md, "DDR5").

Example:
    >>> import json, pathlib
    >>> path = pathlib.Path(__file__).parents[3] / "examples" / "ddr5_drampower_test.json"
    >>> spec = load_memspec_ddr5(path)
    >>> spec.nbr_of_banks, spec.banks_per_group, spec.trfc, spec.trfcsb, spec.refresh_currents
    (16, 8, 25, 20, ('idd5b', 'ipp5b'))
"""

from __future__ import annotations

import copy
import json
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from hdeem_watch.dram import spec_fields as fields
from hdeem_watch.errors import InputError, not_a_file_error

#: memarchitecturespec: JSON key -> attribute (non-negative integers; DRAMUtils requires them all).
ARCH_FIELDS: dict[str, str] = {
    "nbrOfChannels": "nbr_of_channels", "nbrOfDevices": "nbr_of_devices", "nbrOfRanks": "nbr_of_ranks",
    "nbrOfDIMMRanks": "nbr_of_dimm_ranks", "nbrOfPhysicalRanks": "nbr_of_physical_ranks",
    "nbrOfLogicalRanks": "nbr_of_logical_ranks", "nbrOfBanks": "nbr_of_banks",
    "nbrOfBankGroups": "nbr_of_bankgroups", "nbrOfRows": "nbr_of_rows", "nbrOfColumns": "nbr_of_columns",
    "burstLength": "burst_length", "dataRate": "data_rate", "width": "width", "RefMode": "ref_mode",
    "cmdMode": "cmd_mode", "RAAIMT": "raaimt", "RAAMMT": "raammt", "RAADEC": "raadec",
}
#: memarchitecturespec fields the model divides by or counts with: must be > 0.
POSITIVE_ARCH: tuple[str, ...] = ("nbrOfRanks", "nbrOfBanks", "nbrOfBankGroups", "nbrOfRows", "nbrOfColumns",
                                  "burstLength", "dataRate", "width")

#: memtimingspec fields (cycles) of DRAMUtils' MemTimingSpecTypeDDR5, all mandatory.
TIMING_FIELDS: tuple[str, ...] = (
    "RAS", "RCD", "RTP", "WL", "WR", "RP", "PPD", "RL", "RPRE", "RPST", "RDDQS", "WPRE", "WPST",
    "CCD_L_slr", "CCD_L_WR_slr", "CCD_L_WR2_slr", "CCD_M_slr", "CCD_M_WR_slr", "CCD_S_slr", "CCD_S_WR_slr",
    "CCD_dlr", "CCD_WR_dlr", "CCD_WR_dpr", "RRD_L_slr", "RRD_S_slr", "RRD_dlr", "FAW_slr", "FAW_dlr",
    "WTR_L", "WTR_M", "WTR_S", "RFC1_slr", "RFC2_slr", "RFC1_dlr", "RFC2_dlr", "RFC1_dpr", "RFC2_dpr",
    "RFCsb_slr", "RFCsb_dlr", "REFI1", "REFI2", "REFISB", "REFSBRD_slr", "REFSBRD_dlr", "RTRS", "CPDED",
    "PD", "XP", "ACTPDEN", "PRPDEN", "REFPDEN",
)
#: Timings the core model uses that must be positive (it divides by RAS).
POSITIVE_TIMINGS: tuple[str, ...] = ("RAS",)

#: mempowerspec currents (amperes per device), all mandatory, in DRAMUtils' order.
CURRENT_FIELDS: tuple[str, ...] = (
    "idd0", "idd2n", "idd3n", "idd4r", "idd4w", "idd5c", "idd6n", "idd2p", "idd3p",
    "ipp0", "ipp2n", "ipp3n", "ipp4r", "ipp4w", "ipp5c", "ipp6n", "ipp2p", "ipp3p",
    "idd5b", "idd5f", "ipp5b", "ipp5f",
)
#: Optional bank-wise model currents (default: Iβ = IDD0 resp. IPP0).
BETA_CURRENTS: tuple[str, ...] = ("iBeta_vdd", "iBeta_vpp")
VOLTAGES: tuple[str, ...] = ("vdd", "vpp", "vddq")

@dataclass(frozen=True)
class MemSpecDDR5:
    """A validated DDR5 memspec (one channel as DRAMPower sees it: ranks of identical devices).

    Attributes:
        memory_id: ``memoryId``.
        memory_type: ``memoryType`` (``"DDR5"``).
        nbr_of_devices: devices per rank (a 0 in the file counts as 1, as in DRAMPower).
        nbr_of_ranks, nbr_of_banks, nbr_of_bankgroups, nbr_of_rows, nbr_of_columns, burst_length,
            data_rate, width, ref_mode: memarchitecturespec (banks per rank).
        arch: every memarchitecturespec field as read (JSON spelling).
        tck_s: ``tCK`` in seconds.
        timings: every other memtimingspec field, in cycles (JSON spelling).
        currents: amperes per device by lower-case name (``"idd5c"``, ``"ibeta_vdd"`` only when given).
        vdd, vpp, vddq: supply voltages in volts (``vddq`` feeds only DRAMPower's interface model).
        fact_rho: ``bankwisespec.factRho`` (1 when absent).
    """

    memory_id: str
    memory_type: str
    nbr_of_devices: int
    nbr_of_ranks: int
    nbr_of_banks: int
    nbr_of_bankgroups: int
    nbr_of_rows: int
    nbr_of_columns: int
    burst_length: int
    data_rate: int
    width: int
    ref_mode: int
    arch: Mapping[str, int]
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
        """Hash of the fields the model uses (mappings as sorted items)."""
        return hash((self.memory_id, self.nbr_of_devices, self.nbr_of_ranks, self.nbr_of_banks, self.tck_s,
                     tuple(sorted(self.timings.items())), tuple(sorted(self.currents.items())),
                     self.vdd, self.vpp, self.fact_rho, self.ref_mode, self.burst_length, self.data_rate))

    @property
    def banks_per_group(self) -> int:
        """Banks in one bank group (``nbrOfBanks / nbrOfBankGroups``)."""
        return self.nbr_of_banks // self.nbr_of_bankgroups

    @property
    def trfc(self) -> int:
        """All-bank refresh time in cycles: ``RFC2_slr`` in refresh mode 2, else ``RFC1_slr``."""
        return int(self.timings["RFC2_slr" if self.ref_mode == 2 else "RFC1_slr"])

    @property
    def trfcsb(self) -> int:
        """Same-bank refresh time in cycles (``RFCsb_slr``)."""
        return int(self.timings["RFCsb_slr"])

    @property
    def refresh_currents(self) -> tuple[str, str]:
        """(VDD, VPP) all-bank refresh currents of the refresh mode: IDD5F/IPP5F in mode 2, else IDD5B/IPP5B."""
        return ("idd5f", "ipp5f") if self.ref_mode == 2 else ("idd5b", "ipp5b")

    @property
    def burst_cycles(self) -> float:
        """Clock cycles of one burst: burstLength / dataRate."""
        return self.burst_length / self.data_rate

    def with_currents(self, currents: Mapping[str, float]) -> MemSpecDDR5:
        """A copy with some currents replaced (lower-case names, amperes per device), validated.

        Raises:
            InputError: an unknown name or an implausible value.
        """
        known = {key.lower(): key for key in (*CURRENT_FIELDS, *BETA_CURRENTS)}
        merged, keys = dict(self.currents), dict(self._current_keys)
        for name, value in currents.items():
            lower = name.lower()
            if lower not in known:
                raise InputError(f"with_currents: unknown current {name!r}; expected one of {sorted(known)}")
            merged[lower] = fields.check_current(f"with_currents: {lower}", value)
            keys.setdefault(lower, known[lower])
        return replace(self, currents=merged, _current_keys=keys)

    def to_json_dict(self) -> dict[str, Any]:
        """The DRAMPower JSON tree (``{"memspec": {...}}``) with this spec's currents, original spelling."""
        tree = copy.deepcopy(dict(self._raw))
        power = tree.setdefault("memspec", {}).setdefault("mempowerspec", {})
        for lower, key in self._current_keys.items():
            power[key] = float(self.currents[lower])
        return tree


def _architecture(spec: Mapping[str, Any], where: str) -> dict[str, int]:
    arch = fields.section(spec, "memarchitecturespec", where)
    at = f"{where}: memspec.memarchitecturespec"
    values = {key: fields.int_field(arch, key, at, positive=key in POSITIVE_ARCH) for key in ARCH_FIELDS}
    if "maxBurstLength" in arch:
        values["maxBurstLength"] = fields.int_field(arch, "maxBurstLength", at, positive=False)
    if values["RefMode"] not in (1, 2):
        raise InputError(f"{at}.RefMode = {values['RefMode']!r}: expected 1 or 2")
    if values["nbrOfBanks"] % values["nbrOfBankGroups"]:
        raise InputError(f"{at}: nbrOfBanks = {values['nbrOfBanks']} is not a multiple of "
                         f"nbrOfBankGroups = {values['nbrOfBankGroups']}")
    return values


def _power(spec: Mapping[str, Any], where: str) -> tuple[dict[str, float], dict[str, float], dict[str, str]]:
    power = fields.section(spec, "mempowerspec", where)
    pt = f"{where}: memspec.mempowerspec"
    volts = fields.voltages(power, pt, VOLTAGES)
    currents: dict[str, float] = {}
    keys: dict[str, str] = {}
    for key in (*CURRENT_FIELDS, *BETA_CURRENTS):
        if key not in power:  # DRAMUtils matches the exact spelling
            if key in CURRENT_FIELDS:
                raise InputError(f"{pt}: missing field {key}")
            continue
        currents[key.lower()] = fields.check_current(f"{pt}.{key}", power[key])
        keys[key.lower()] = key
    return volts, currents, keys


def is_ddr5(data: Any) -> bool:
    """Whether a parsed memspec JSON tree says ``memoryType`` DDR5 (for dispatching by standard)."""
    spec = data.get("memspec", data) if isinstance(data, Mapping) else None
    memory_type = spec.get("memoryType") if isinstance(spec, Mapping) else None
    return isinstance(memory_type, str) and memory_type.upper() == "DDR5"


def parse_memspec_ddr5(data: Any, where: str = "memspec", *, allow_unphysical: bool = False) -> MemSpecDDR5:
    """Validate a parsed DRAMPower DDR5 memspec JSON tree.

    Args:
        data: the parsed JSON (``{"memspec": {...}}``).
        where: the file name used in messages.
        allow_unphysical: skip the physical check (:mod:`hdeem_watch.dram.memspec_ddr5_check`).

    Raises:
        InputError: one line naming ``where``, the field and what was expected.
    """
    spec = data.get("memspec") if isinstance(data, Mapping) else None
    memory_type, memory_id = fields.header(spec, where, "DDR5")
    assert isinstance(spec, Mapping)
    arch = _architecture(spec, where)
    tck, timings = fields.timings(spec, where, TIMING_FIELDS, POSITIVE_TIMINGS)
    volts, currents, keys = _power(spec, where)
    fact_rho = fields.fact_rho(spec, where)
    fields.section(spec, "memimpedancespec", where)
    if "dataratespec" in spec:
        fields.section(spec, "dataratespec", where)
    out = MemSpecDDR5(
        memory_id=memory_id, memory_type=memory_type, nbr_of_devices=max(1, arch["nbrOfDevices"]),
        nbr_of_ranks=arch["nbrOfRanks"], nbr_of_banks=arch["nbrOfBanks"], nbr_of_bankgroups=arch["nbrOfBankGroups"],
        nbr_of_rows=arch["nbrOfRows"], nbr_of_columns=arch["nbrOfColumns"], burst_length=arch["burstLength"],
        data_rate=arch["dataRate"], width=arch["width"], ref_mode=arch["RefMode"], arch=arch, tck_s=tck,
        timings=timings, currents=currents, fact_rho=fact_rho, _raw=copy.deepcopy(dict(data)), _current_keys=keys,
        **volts)
    if not allow_unphysical:
        from hdeem_watch.dram.memspec_ddr5_check import check_physical_ddr5

        check_physical_ddr5(out, where)
    return out


def read_memspec_json(path: str | Path) -> Any:
    """The parsed JSON of a memspec file (any standard).

    Raises:
        InputError: a missing or unreadable file, or invalid JSON (one line).
    """
    path = Path(path)
    if path.is_dir() or not path.exists():
        raise not_a_file_error(path, "memspec file")
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as error:
        raise InputError(f"{path}: cannot read memspec: {error.strerror or error}") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a UTF-8 text file; expected a DRAMPower JSON memspec") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as error:
        raise InputError(f"{path}: invalid JSON at line {error.lineno} column {error.colno}: {error.msg}") from None


def load_memspec_ddr5(path: str | Path, *, allow_unphysical: bool = False) -> MemSpecDDR5:
    """Read and validate a DRAMPower DDR5 memspec file.

    Raises:
        InputError: unreadable file, invalid JSON, or an invalid field (named, one line).
    """
    return parse_memspec_ddr5(read_memspec_json(path), where=str(path), allow_unphysical=allow_unphysical)


def ddr5_memspec(value: str, *, allow_unphysical: bool = False) -> MemSpecDDR5 | None:
    """The DDR5 memspec ``value`` names, or None when it names a preset or a non-DDR5 file.

    Raises:
        InputError: a DDR5 file that is malformed or (without ``allow_unphysical``) unphysical.
    """
    path = Path(str(value))
    if str(value).startswith("preset:") or not path.is_file():
        return None
    data = read_memspec_json(path)
    if not is_ddr5(data):
        return None
    return parse_memspec_ddr5(data, where=str(path), allow_unphysical=allow_unphysical)
