"""IMC event encodings per CPU generation, each entry traceable to Intel's public event files.

Every Intel :class:`ImcEvent` below is copied by name, ``EventCode`` and ``UMask`` from Intel's perfmon
event files (github.com/intel/perfmon, the upstream of the Linux kernel's
``tools/perf/pmu-events/arch/x86/<gen>/uncore-memory.json``), read at perfmon commit
:data:`PERFMON_COMMIT`; :attr:`EventTable.sources` names the file(s) and version per table, and
``experimental`` marks events from the ``*_uncore_experimental.json`` files. Nothing is derived:
where a role needs several published sub-events (Haswell-EP's activates: ``ACT_COUNT.RD + .WR +
.BYP``), the table lists each and the reader sums them. A role the files do not cover is absent
from the table (and listed in :attr:`EventTable.gaps`); it is never guessed.

AMD Zen 4 and Zen 5 (EPYC 9004 Genoa, 9005 Turin) count DRAM commands in the ``amd_umc_<n>`` PMUs (one
per memory channel, arch/x86/events/amd/uncore.c, PerfMonV2); their events are the Linux perf tool's
``tools/perf/pmu-events/arch/x86/amdzen4|amdzen5/memory-controller.json`` (read at Linux commit
:data:`PERF_JSON_COMMIT`): ``EventCode`` and ``RdWrMask``, which the PMU's ``format/rdwrmask``
(``config:8-9``) places (:attr:`ImcEvent.mask_field`).

Roles (what a counter means for the DRAM model, per channel):

==================  ===============================================================================
``dclk``            DRAM clock ticks while the IMC has a clock (stops in package C3/C6).
``cas_rd``          read CAS commands (with and without auto-precharge, underfills included).
``cas_wr``          write CAS commands (with and without auto-precharge).
``cas_rd_autopre``  the subset of ``cas_rd`` with auto-precharge (RDA) — Ice Lake-SP and later only.
``cas_wr_autopre``  the subset of ``cas_wr`` with auto-precharge (WRA) — Ice Lake-SP and later only.
``act``             activates (all ranks and banks of the channel together).
``pre_page_miss``   explicit precharges for a page miss (the bank scheduler's rd/wr requests; on Ice
                    Lake-SP the non-experimental ``PRE_COUNT.RD`` + ``.WR``, whose umask bits
                    0x04|0x08 are those of the experimental ``PAGE_MISS`` 0x0c).
``pre_page_close``  explicit precharges by the page-close timer (idle page closed).
``pre_underfill``   explicit precharges for an underfill read (Sapphire Rapids' ``PRE_COUNT.UFILL``;
                    ``PRE_COUNT.ALL`` 0xff is exactly RD|WR|UFILL|PGT = 0x11|0x22|0x44|0x88).
``pre_all``         every PRECHARGE command the controller sent (AMD's ``umc_pchg_cmd.all``, which
                    does not say how the precharges divide by cause).
``cas_pch0``        CAS commands of pseudo-channel (DDR5 sub-channel) 0 — Sapphire Rapids.
``cas_pch1``        CAS commands of pseudo-channel 1.
``refresh``         refresh commands (see :attr:`EventTable.refresh_complete`).
``cke_on_rank<n>``  cycles rank n has CKE on (not in power-down or self-refresh).
``ppd_cycles``      cycles every rank of the channel is in precharge power-down.
``sref_cycles``     cycles the IMC is in self-refresh while it still has a clock.
==================  ===============================================================================

Example:
    >>> table = TABLES["haswell-ep"]
    >>> [(e.name, hex(e.event), hex(e.umask)) for e in table.events_of("cas_rd")]
    [('UNC_M_CAS_COUNT.RD', '0x4', '0x3')]
    >>> [e.name for e in table.events_of("act")]
    ['UNC_M_ACT_COUNT.RD', 'UNC_M_ACT_COUNT.WR', 'UNC_M_ACT_COUNT.BYP']
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

#: The intel/perfmon commit the tables were read from (2026-08-13).
PERFMON_COMMIT = "6dadedf3aa483393943e044ba5ec88a4507cd040"
#: The Linux commit the perf tool's AMD ``memory-controller.json`` files were read at.
PERF_JSON_COMMIT = "3c69140734a27f8b145f12fa0ae80c1fe36a02ca"
#: Width of the IMC's programmable counters (``perf_ctr_bits = 48`` of ``hswep_uncore_imc``,
#: ``bdx_uncore_imc``, ``skx_uncore_imc``, ``icx_uncore_imc`` in the kernel's uncore_snbep.c).
IMC_COUNTER_BITS = 48
#: Ranks per channel whose CKE residency the pre-Ice-Lake ``POWER_CKE_CYCLES.RANK<n>`` umasks select.
MAX_CKE_RANKS = 8

ROLES = ("dclk", "cas_rd", "cas_wr", "cas_rd_autopre", "cas_wr_autopre", "act", "pre_page_miss",
         "pre_page_close", "pre_underfill", "pre_all", "refresh", *(f"cke_on_rank{n}" for n in range(MAX_CKE_RANKS)),
         "ppd_cycles", "sref_cycles", "cas_pch0", "cas_pch1")


@dataclass(frozen=True)
class ImcEvent:
    """One published IMC event.

    Attributes:
        name: the publisher's ``EventName`` (Intel's perfmon, or the perf tool's JSON for AMD).
        event: ``EventCode``.
        umask: ``UMask`` (AMD: ``RdWrMask``, 0 when the JSON gives none).
        experimental: from the ``*_uncore_experimental.json`` file (published, not validated by Intel).
        mask_field: the PMU format field that holds :attr:`umask` (``umask``; AMD's UMC: ``rdwrmask``).
    """

    name: str
    event: int
    umask: int
    experimental: bool = False
    mask_field: str = "umask"

    def fields(self) -> dict[str, int]:
        """The format-field values (``event``, ``umask`` or ``rdwrmask``) to encode with the PMU's ``format/``."""
        return {"event": self.event, self.mask_field: self.umask}


@dataclass(frozen=True)
class EventTable:
    """The IMC events of one CPU generation.

    Attributes:
        generation: key, e.g. ``"haswell-ep"``.
        title: human name, e.g. ``"Haswell-EP (Xeon E5 v3)"``.
        sources: the perfmon files (path, version) the entries come from.
        roles: role → the events whose counts add up to it.
        refresh_complete: ``False`` when the files publish only some refresh causes (panic/high
            priority, not opportunistic): ``refresh`` is then a lower bound.
        memory: the DRAM standard the IMC drives (``DDR4`` or ``DDR5``).
        gaps: what this generation's public files do not give, in words.
        pmu_prefix: the PMUs that count these events (``uncore_imc``; AMD: ``amd_umc``).
        notes: facts about the kernel's own names for these events worth saying (one line each).
    """

    generation: str
    title: str
    sources: tuple[str, ...]
    roles: Mapping[str, tuple[ImcEvent, ...]]
    refresh_complete: bool
    memory: str
    gaps: tuple[str, ...] = field(default=())
    pmu_prefix: str = "uncore_imc"
    notes: tuple[str, ...] = field(default=())

    def events_of(self, role: str) -> tuple[ImcEvent, ...]:
        """The events of ``role`` (empty when the generation does not count it)."""
        return self.roles.get(role, ())

    def events(self) -> tuple[ImcEvent, ...]:
        """Every distinct event of the table, in role order."""
        seen: dict[str, ImcEvent] = {}
        for role in ROLES:
            for event in self.events_of(role):
                seen.setdefault(event.name, event)
        return tuple(seen.values())

    def cke_ranks(self) -> int:
        """How many ranks have a CKE-on residency counter."""
        return sum(1 for n in range(MAX_CKE_RANKS) if f"cke_on_rank{n}" in self.roles)


def _cke_ranks(experimental: bool) -> dict[str, tuple[ImcEvent, ...]]:
    return {f"cke_on_rank{n}": (ImcEvent(f"UNC_M_POWER_CKE_CYCLES.RANK{n}", 0x83, 1 << n, experimental),)
            for n in range(MAX_CKE_RANKS)}


def _haswell_broadwell(clock: ImcEvent) -> dict[str, tuple[ImcEvent, ...]]:
    """Haswell-EP and Broadwell-EP publish the same IMC encodings (HSX V29, BDX V23, all non-experimental)."""
    return {
        "dclk": (clock,),
        "cas_rd": (ImcEvent("UNC_M_CAS_COUNT.RD", 0x04, 0x03),),
        "cas_wr": (ImcEvent("UNC_M_CAS_COUNT.WR", 0x04, 0x0C),),
        "act": (ImcEvent("UNC_M_ACT_COUNT.RD", 0x01, 0x01), ImcEvent("UNC_M_ACT_COUNT.WR", 0x01, 0x02),
                ImcEvent("UNC_M_ACT_COUNT.BYP", 0x01, 0x08)),
        "pre_page_miss": (ImcEvent("UNC_M_PRE_COUNT.PAGE_MISS", 0x02, 0x01),),
        "pre_page_close": (ImcEvent("UNC_M_PRE_COUNT.PAGE_CLOSE", 0x02, 0x02),),
        "refresh": (ImcEvent("UNC_M_DRAM_REFRESH.PANIC", 0x05, 0x02), ImcEvent("UNC_M_DRAM_REFRESH.HIGH", 0x05, 0x04)),
        **_cke_ranks(experimental=False),
        "ppd_cycles": (ImcEvent("UNC_M_POWER_CHANNEL_PPD", 0x85, 0x00),),
        "sref_cycles": (ImcEvent("UNC_M_POWER_SELF_REFRESH", 0x43, 0x00),),
    }


def _skylake_cascade_lake(refresh: bool) -> dict[str, tuple[ImcEvent, ...]]:
    """Skylake-SP (SKX V1.37) and Cascade Lake-SP (CLX V1.25) publish identical IMC encodings, except
    that CLX publishes no ``DRAM_REFRESH`` event (``refresh=False``)."""
    roles = {
        "dclk": (ImcEvent("UNC_M_CLOCKTICKS", 0x00, 0x00),),
        "cas_rd": (ImcEvent("UNC_M_CAS_COUNT.RD", 0x04, 0x03),),
        "cas_wr": (ImcEvent("UNC_M_CAS_COUNT.WR", 0x04, 0x0C),),
        "act": (ImcEvent("UNC_M_ACT_COUNT.RD", 0x01, 0x01, True), ImcEvent("UNC_M_ACT_COUNT.WR", 0x01, 0x02),
                ImcEvent("UNC_M_ACT_COUNT.BYP", 0x01, 0x08, True)),
        "pre_page_miss": (ImcEvent("UNC_M_PRE_COUNT.PAGE_MISS", 0x02, 0x01),),
        "pre_page_close": (ImcEvent("UNC_M_PRE_COUNT.PAGE_CLOSE", 0x02, 0x02, True),),
        "refresh": (ImcEvent("UNC_M_DRAM_REFRESH.PANIC", 0x05, 0x02, True),
                    ImcEvent("UNC_M_DRAM_REFRESH.HIGH", 0x05, 0x04, True)),
        **_cke_ranks(experimental=True),
        "ppd_cycles": (ImcEvent("UNC_M_POWER_CHANNEL_PPD", 0x85, 0x00),),
        "sref_cycles": (ImcEvent("UNC_M_POWER_SELF_REFRESH", 0x43, 0x00),),
    }
    if not refresh:
        del roles["refresh"]
    return roles


_GAPS_PRE_ICX = (
    "RDA/WRA: CAS_COUNT.RD/.WR include auto-precharge CASes; no published umask separates them",
    "refresh: only DRAM_REFRESH.PANIC and .HIGH are published (no opportunistic refreshes)",
    "activates, precharges and CASes per rank: the counters are per channel",
    "active vs precharge standby: no event counts cycles with a bank open",
    "active vs precharge power-down per rank: only the channel-wide all-ranks-in-PPD count exists",
    "precharges by requester: PRE_COUNT.RD/.WR/.BYP (umasks 0x04/0x08/0x10) group the same precharges as "
    "PAGE_MISS/PAGE_CLOSE (0x01/0x02) by another key, and the files do not say which cause a bypass "
    "precharge has, so BYP may overlap PAGE_MISS: only PAGE_MISS and PAGE_CLOSE are used, never added to BYP",
)
_GAPS_ICX_SPR = (
    "CKE residency per rank: the published POWER_CKE_CYCLES.LOW_<n> umasks select a DIMM ID and "
    "their description (CKE on) contradicts their name (CKE low); not used",
    "activates, precharges and CASes per rank: the counters are per channel",
    "active vs precharge standby: no event counts cycles with a bank open",
)

#: perf's ``clockticks`` alias of the SPR IMC is not the DRAM clock (kernel ``spr_uncore_imc_events``).
SPR_CLOCKTICKS_NOTE = ("perf's uncore_imc_<n>/clockticks/ alias on Sapphire Rapids is event=0x01,umask=0x00 "
                       "(spr_uncore_imc_events of uncore_snbep.c, lore.kernel.org 20230419214241.2310385-1-eranian@google.com), "
                       "which perfmon names UNC_M_HCLOCKTICKS (the controller's HCLK, by its name); the DRAM clock "
                       "(dclk) is UNC_M_CLOCKTICKS event=0x01,umask=0x01, counted here")


def _amd_umc_roles() -> dict[str, tuple[ImcEvent, ...]]:
    """Zen 4 and Zen 5 publish the same UMC encodings (``umc_*`` of memory-controller.json; ``.rd``/``.wr``
    select with ``RdWrMask`` 1/2, ``.all`` has none)."""
    def umc(name: str, code: int, rdwr: int = 0) -> ImcEvent:
        return ImcEvent(name, code, rdwr, mask_field="rdwrmask")

    return {
        "dclk": (umc("umc_mem_clk", 0x00),),
        "cas_rd": (umc("umc_cas_cmd.rd", 0x0A, 0x1),),
        "cas_wr": (umc("umc_cas_cmd.wr", 0x0A, 0x2),),
        "act": (umc("umc_act_cmd.all", 0x05),),
        "pre_all": (umc("umc_pchg_cmd.all", 0x06),),
    }


#: What stands in for the DRAM energy sensor AMD lacks.
AMD_ENERGY_NOTE = ("DRAM energy: AMD has no DRAM energy sensor (RAPL has package and core domains only); a job's "
                   "DRAM energy is modelled from these counts with a memspec's currents: its datasheet values, "
                   "or a calibrated memspec imported from a node that has DRAM sensors (hdeem-watch node says "
                   "which memspec applies)")
_GAPS_AMD_UMC = (
    "refresh: no published UMC refresh event (refreshes are nominal, one per tREFI)",
    "power-down and self-refresh residency: no published UMC event (power-down taken as 0)",
    "RDA/WRA: umc_cas_cmd does not separate auto-precharge CASes",
    "precharges by cause: umc_pchg_cmd.all counts every PRECHARGE command (.rd/.wr split by requester only)",
    "sub-channels and ranks: each amd_umc PMU counts one channel (both DDR5 sub-channels, every rank)",
)

TABLES: dict[str, EventTable] = {
    "haswell-ep": EventTable(
        generation="haswell-ep", title="Haswell-EP (Xeon E5 v3)", memory="DDR4",
        sources=("HSX/events/haswellx_uncore.json V29",),
        roles=_haswell_broadwell(ImcEvent("UNC_M_DCLOCKTICKS", 0x00, 0x00)),
        refresh_complete=False, gaps=_GAPS_PRE_ICX),
    "broadwell-ep": EventTable(
        generation="broadwell-ep", title="Broadwell-EP (Xeon E5 v4)", memory="DDR4",
        sources=("BDX/events/broadwellx_uncore.json V23",),
        roles=_haswell_broadwell(ImcEvent("UNC_M_DCLOCKTICKS", 0x00, 0x00)),
        refresh_complete=False, gaps=_GAPS_PRE_ICX),
    "skylake-sp": EventTable(
        generation="skylake-sp", title="Skylake-SP (Xeon Scalable 1st gen)", memory="DDR4",
        sources=("SKX/events/skylakex_uncore.json V1.37", "SKX/events/skylakex_uncore_experimental.json V1.37"),
        roles=_skylake_cascade_lake(refresh=True), refresh_complete=False, gaps=_GAPS_PRE_ICX),
    "cascade-lake-sp": EventTable(
        generation="cascade-lake-sp", title="Cascade Lake-SP (Xeon Scalable 2nd gen)", memory="DDR4",
        sources=("CLX/events/cascadelakex_uncore.json V1.25",
                 "CLX/events/cascadelakex_uncore_experimental.json V1.25"),
        roles=_skylake_cascade_lake(refresh=False), refresh_complete=False,
        gaps=(*_GAPS_PRE_ICX[:1],
              "refresh: the CLX files publish no DRAM_REFRESH event (refreshes are nominal, one per tREFI)",
              *_GAPS_PRE_ICX[2:])),
    "ice-lake-sp": EventTable(
        generation="ice-lake-sp", title="Ice Lake-SP (Xeon Scalable 3rd gen)", memory="DDR4",
        sources=("ICX/events/icelakex_uncore.json V1.30", "ICX/events/icelakex_uncore_experimental.json V1.30"),
        roles={
            "dclk": (ImcEvent("UNC_M_CLOCKTICKS", 0x00, 0x00),),
            "cas_rd": (ImcEvent("UNC_M_CAS_COUNT.RD", 0x04, 0x0F),),
            "cas_wr": (ImcEvent("UNC_M_CAS_COUNT.WR", 0x04, 0x30),),
            "cas_rd_autopre": (ImcEvent("UNC_M_CAS_COUNT.RD_PRE_REG", 0x04, 0x02, True),
                               ImcEvent("UNC_M_CAS_COUNT.RD_PRE_UNDERFILL", 0x04, 0x08, True)),
            "cas_wr_autopre": (ImcEvent("UNC_M_CAS_COUNT.WR_PRE", 0x04, 0x20, True),),
            "act": (ImcEvent("UNC_M_ACT_COUNT.ALL", 0x01, 0x0B),),
            # PAGE_MISS (0x0c, experimental) is exactly the bits of the non-experimental RD (0x04) and WR (0x08)
            "pre_page_miss": (ImcEvent("UNC_M_PRE_COUNT.RD", 0x02, 0x04), ImcEvent("UNC_M_PRE_COUNT.WR", 0x02, 0x08)),
            "pre_page_close": (ImcEvent("UNC_M_PRE_COUNT.PGT", 0x02, 0x10),),
            "refresh": (ImcEvent("UNC_M_DRAM_REFRESH.OPPORTUNISTIC", 0x45, 0x01),
                        ImcEvent("UNC_M_DRAM_REFRESH.PANIC", 0x45, 0x02),
                        ImcEvent("UNC_M_DRAM_REFRESH.HIGH", 0x45, 0x04)),
            "ppd_cycles": (ImcEvent("UNC_M_POWER_CHANNEL_PPD", 0x85, 0x00, True),),
            "sref_cycles": (ImcEvent("UNC_M_POWER_SELF_REFRESH", 0x43, 0x00, True),),
        },
        refresh_complete=True,
        gaps=(*_GAPS_ICX_SPR,
              "inactive channels: the kernel registers 3 boxes per controller (uncore_imc_<3m+2> is the third "
              "channel, inactive on most parts) and an inactive box reads 0 (kernel commit 496a18f09374)")),
    "sapphire-rapids": EventTable(
        generation="sapphire-rapids", title="Sapphire Rapids (Xeon Scalable 4th gen)", memory="DDR5",
        sources=("SPR/events/sapphirerapids_uncore.json V1.39",
                 "SPR/events/sapphirerapids_uncore_experimental.json V1.39"),
        roles={
            "dclk": (ImcEvent("UNC_M_CLOCKTICKS", 0x01, 0x01),),
            "cas_rd": (ImcEvent("UNC_M_CAS_COUNT.RD", 0x05, 0xCF),),
            "cas_wr": (ImcEvent("UNC_M_CAS_COUNT.WR", 0x05, 0xF0),),
            "cas_rd_autopre": (ImcEvent("UNC_M_CAS_COUNT.RD_PRE_REG", 0x05, 0xC2, True),
                               ImcEvent("UNC_M_CAS_COUNT.RD_PRE_UNDERFILL", 0x05, 0xC8, True)),
            "cas_wr_autopre": (ImcEvent("UNC_M_CAS_COUNT.WR_PRE", 0x05, 0xE0, True),),
            "act": (ImcEvent("UNC_M_ACT_COUNT.ALL", 0x02, 0xFF),),
            "pre_page_miss": (ImcEvent("UNC_M_PRE_COUNT.RD", 0x03, 0x11), ImcEvent("UNC_M_PRE_COUNT.WR", 0x03, 0x22)),
            "pre_page_close": (ImcEvent("UNC_M_PRE_COUNT.PGT", 0x03, 0x88),),
            "pre_underfill": (ImcEvent("UNC_M_PRE_COUNT.UFILL", 0x03, 0x44, True),),
            "refresh": (ImcEvent("UNC_M_DRAM_REFRESH.PANIC", 0x45, 0x12, True),
                        ImcEvent("UNC_M_DRAM_REFRESH.HIGH", 0x45, 0x24, True)),
            "ppd_cycles": (ImcEvent("UNC_M_POWER_CHANNEL_PPD", 0x85, 0x00, True),),
            "sref_cycles": (ImcEvent("UNC_M_POWER_SELF_REFRESH", 0x43, 0x00, True),),
            "cas_pch0": (ImcEvent("UNC_M_CAS_COUNT.PCH0", 0x05, 0x40, True),),
            "cas_pch1": (ImcEvent("UNC_M_CAS_COUNT.PCH1", 0x05, 0x80, True),),
        },
        refresh_complete=False,
        gaps=(*_GAPS_ICX_SPR,
              "refresh: only DRAM_REFRESH.PANIC and .HIGH are published (no opportunistic refreshes)",
              "pseudo-channels: CAS_COUNT.PCH0/.PCH1 split the CASes by DDR5 sub-channel; ACT_COUNT.ALL and "
              "the power-state events are per channel (both sub-channels)"),
        notes=(SPR_CLOCKTICKS_NOTE,)),
    "zen4": EventTable(
        generation="zen4", title="AMD Zen 4 (EPYC 9004 Genoa)", memory="DDR5", pmu_prefix="amd_umc",
        sources=("tools/perf/pmu-events/arch/x86/amdzen4/memory-controller.json",),
        roles=_amd_umc_roles(), refresh_complete=False, gaps=_GAPS_AMD_UMC, notes=(AMD_ENERGY_NOTE,)),
    "zen5": EventTable(
        generation="zen5", title="AMD Zen 5 (EPYC 9005 Turin)", memory="DDR5", pmu_prefix="amd_umc",
        sources=("tools/perf/pmu-events/arch/x86/amdzen5/memory-controller.json",),
        roles=_amd_umc_roles(), refresh_complete=False, gaps=_GAPS_AMD_UMC, notes=(AMD_ENERGY_NOTE,)),
}
