"""The integrated memory controller's PMUs under ``/sys/bus/event_source/devices`` (root injected).

The Linux uncore driver registers one PMU per IMC *channel box* and names it
``uncore_imc_<box>`` (``arch/x86/events/intel/uncore.c`` names a type with several boxes
``uncore_<type>_<idx>``; ``uncore_snbep.c`` declares ``hswep_uncore_imc``/``bdx_uncore_imc`` with
``.name = "imc", .num_boxes = 8`` and maps PCI device "MC<m> Channel <c>" to box ``4·m + c``;
``icx_uncore_imc`` has 12 boxes, 3 per controller). A box index is therefore a channel *position
within a socket*, not a node-wide channel number, and only boxes that exist on the die are
registered: a Haswell-EP die with two home agents of two channels each shows ``uncore_imc_0, 1, 4,
5``. Each PMU counts on every socket; its ``cpumask`` lists one CPU per socket, and an event opened
on that CPU counts that socket's channel. So a node channel is a pair (socket, box).

Ice Lake-SP and later also expose ``uncore_imc_free_running_<controller>``: fixed free-running
counters per memory *controller*. What they count differs by generation (``uncore_snbep.c``):
Ice Lake-SP's ``icx_uncore_imc_freerunning_events`` are ``dclk``, ``read``, ``write`` (DDR bandwidth)
and ``ddrt_read``, ``ddrt_write`` (Optane DCPMM bandwidth); Sapphire Rapids'
``spr_uncore_imc_freerunning_events`` are ``dclk``, ``rpq_cycles`` and ``wpq_cycles`` (read and write
pending-queue cycles, no bandwidth). The event names are read from each PMU's ``events/``
directory, never assumed. None has ACT/PRE/power-state events, so they are listed but not used for
command statistics.

Sapphire Rapids' programmable IMC PMUs (``spr_uncore_imc``, discovered from the uncore discovery
table) are ``uncore_imc_<box>`` too, with the format ``umask`` = ``config:8-15,32-55`` (``umask_ext4``)
and the kernel aliases ``clockticks`` (event 0x01, umask 0x00), ``cas_count_read``/``_write``.

AMD Zen 4 and later count DRAM commands in ``amd_umc_<n>`` PMUs (arch/x86/events/amd/uncore.c,
``amd_uncore_umc_ctx_init``): one per active memory channel (UMC), numbered across the node, each
group of UMCs (a socket) enumerated through CPUID 0x80000022; the ``cpumask`` lists the one CPU that
counts that group, and the format is ``event`` ``config:0-7`` and ``rdwrmask`` ``config:8-9``
(``amd_uncore_umc_format_attr``); no ``events/`` aliases (perf's JSON names the events). So an AMD
node channel is one PMU, its socket the rank of its ``cpumask`` CPU among the UMC PMUs'.

Each PMU directory holds ``type`` (the ``perf_event_attr.type`` to open it with), ``cpumask`` (a CPU
list such as ``0,12``) and ``format/<field>`` files (:mod:`hdeem_watch.counters.event_format`).

Example:
    >>> parse_cpu_list("0-1,12")
    (0, 1, 12)
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from hdeem_watch.counters.event_format import FormatField, parse_format
from hdeem_watch.errors import InputError

#: Where the kernel lists PMUs.
DEVICES_DIR = "bus/event_source/devices"
DEFAULT_SYSFS_ROOT = "/sys"

_IMC = re.compile(r"^uncore_imc_(\d+)$")
_IMC_FREE = re.compile(r"^uncore_imc_free_running_(\d+)$")
_UMC = re.compile(r"^amd_umc_(\d+)$")


@dataclass(frozen=True)
class UncorePmu:
    """One uncore IMC PMU as sysfs describes it.

    Attributes:
        name: directory name, e.g. ``uncore_imc_4``.
        box: the box index from the name (channel position within a socket, or the controller for
            free-running PMUs).
        free_running: an ``uncore_imc_free_running_*`` PMU.
        pmu_type: the ``type`` file: ``perf_event_attr.type``.
        cpus: the ``cpumask`` CPUs, one per socket, in socket order.
        formats: ``format/`` field name → bit field.
        events: the kernel's event aliases in ``events/`` (``.scale``/``.unit`` companions left out).
        aliases: alias name → its encoding text (``event=0x05,umask=0xcf``).
    """

    name: str
    box: int
    free_running: bool
    pmu_type: int
    cpus: tuple[int, ...]
    formats: dict[str, FormatField]
    events: tuple[str, ...] = ()
    aliases: dict[str, str] = field(default_factory=dict, compare=False)

    @property
    def umc(self) -> bool:
        """An AMD ``amd_umc_<n>`` PMU (one channel, one counting CPU)."""
        return self.name.startswith("amd_umc_")

    def alias_of(self, fields: dict[str, int]) -> str | None:
        """The kernel alias whose encoding sets exactly these field values (``None``: no alias)."""
        for name, text in sorted(self.aliases.items()):
            try:
                parsed = {k: int(v, 0) for k, _, v in (part.partition("=") for part in text.split(","))}
            except ValueError:
                continue
            if {k: v for k, v in parsed.items() if v} == {k: v for k, v in fields.items() if v}:
                return name
        return None


def parse_cpu_list(text: str, where: str = "cpumask") -> tuple[int, ...]:
    """A kernel CPU list (``0,12`` or ``0-3,8``) as a tuple of CPU numbers.

    Raises:
        InputError: naming ``where`` when it is not a CPU list.
    """
    cpus: list[int] = []
    for part in text.strip().split(","):
        bounds = part.split("-")
        if not part or len(bounds) > 2 or not all(b.isdigit() for b in bounds):
            raise InputError(f"{where}: {text.strip()!r} is not a CPU list like '0,12' or '0-3'")
        cpus.extend(range(int(bounds[0]), int(bounds[-1]) + 1))
    return tuple(cpus)


def devices_dir(sysfs_root: str | Path = DEFAULT_SYSFS_ROOT) -> Path:
    """``<sysfs_root>/bus/event_source/devices``."""
    return Path(sysfs_root) / DEVICES_DIR


def list_pmus(sysfs_root: str | Path = DEFAULT_SYSFS_ROOT) -> list[str]:
    """Names of every PMU the kernel registered (empty when the directory does not exist)."""
    base = devices_dir(sysfs_root)
    if not base.is_dir():
        return []
    return sorted(entry.name for entry in base.iterdir())


def read_pmu(path: Path) -> UncorePmu:
    """Read one ``uncore_imc_*`` PMU directory.

    Raises:
        InputError: naming the file when ``type``, ``cpumask`` or a ``format/`` file is missing or
            malformed.
    """
    name = path.name
    match = _IMC.match(name) or _IMC_FREE.match(name) or _UMC.match(name)
    if match is None:
        raise InputError(f"{path}: not an uncore_imc_<n>, uncore_imc_free_running_<n> or amd_umc_<n> PMU")
    try:
        type_text = (path / "type").read_text().strip()
        cpumask_text = (path / "cpumask").read_text()
        format_files = sorted((path / "format").iterdir())
    except OSError as error:
        raise InputError(f"{error.filename}: cannot read ({error.strerror})") from None
    if not type_text.isdigit():
        raise InputError(f"{path / 'type'}: {type_text!r} is not a PMU type number")
    formats = {f.name: parse_format(f.read_text(), where=str(f)) for f in format_files}
    alias_files = [e for e in (path / "events").glob("*") if "." not in e.name]
    aliases = {e.name: e.read_text().strip() for e in alias_files}
    return UncorePmu(name=name, box=int(match.group(1)), free_running=name.startswith("uncore_imc_free"),
                     pmu_type=int(type_text), cpus=parse_cpu_list(cpumask_text, where=str(path / "cpumask")),
                     formats=formats, events=tuple(sorted(aliases)), aliases=aliases)


def is_memory_pmu(name: str) -> bool:
    """An ``uncore_imc_*`` or ``amd_umc_*`` PMU name."""
    return bool(_IMC.match(name) or _IMC_FREE.match(name) or _UMC.match(name))


def discover_imc_pmus(sysfs_root: str | Path = DEFAULT_SYSFS_ROOT) -> list[UncorePmu]:
    """Every memory-controller PMU: ``uncore_imc_*`` (programmable ones first, by box; then free-running
    ones) and AMD's ``amd_umc_*`` (by index).

    Raises:
        InputError: a PMU directory that is malformed (see :func:`read_pmu`).
    """
    base = devices_dir(sysfs_root)
    pmus = [read_pmu(base / name) for name in list_pmus(sysfs_root) if is_memory_pmu(name)]
    return sorted(pmus, key=lambda p: (p.umc, p.free_running, p.box))
