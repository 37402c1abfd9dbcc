"""Builds the node fixture trees the tests read (``build(dest)``; the tests call it once per session into
a temporary directory, so the trees are not committed).

Each node: a sysfs subset laid out as Linux prints it (``devices/system/cpu``, ``devices/system/node``,
``devices/system/edac/mc``) and a ``dmidecode -t 17`` print-out in the spelling of the dmidecode
version such a node ran. Sizes, speeds, part numbers and core counts are those of real products
(Xeon E5-2680 v3, Gold 6148, Gold 6330, Silver 4116, EPYC 7302, Platinum 8480+, EPYC 9654; the modules
named in each file). The two DDR5 nodes (``sapphire-rapids-2s``, ``genoa-2s``) also carry the processor
records (DMI type 4) and a ``class/powercap`` tree: RAPL DRAM zones on the Intel node, none on the AMD one.

Two nodes take their ``dmidecode`` print-out from public captures kept in ``captures/`` (excerpts with
their source in the header): ``haswell-ep-x10drl-cod`` (Supermicro X10DRL-i, 2 x Xeon E5-2695 v3
with Cluster-on-Die, ``Type: Other`` DDR4 RDIMMs, bank locators whose ``NodeN`` repeats the socket)
and ``skylake-sp-x11ddw-snc2`` (Supermicro X11DDW-L, 2 x Xeon Gold 6148 with SNC, bank locators
whose ``NodeN`` is the memory controller); their sysfs trees follow the topology those pages print.

Usage: ``python3 tests/node/make_fixtures.py DIR`` writes the trees into DIR (to look at them).
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

CAPTURES = Path(__file__).resolve().parent / "captures"


def cpu_list(cpus: list[int]) -> str:
    """Kernel CPU-list spelling of sorted CPUs (``0-11,24-35``)."""
    out: list[str] = []
    start = prev = cpus[0]
    for c in cpus[1:]:
        if c == prev + 1:
            prev = c
            continue
        out.append(f"{start}-{prev}" if prev != start else f"{start}")
        start = prev = c
    out.append(f"{start}-{prev}" if prev != start else f"{start}")
    return ",".join(out)


def write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text + "\n")


def cpus(root: Path, sockets: int, cores: int, threads: int, *, die_id: bool, numa: list[list[int]] | None = None) -> None:
    """Linux numbering: socket s core c thread t -> CPU t*sockets*cores + s*cores + c (only the
    topology files the reader needs: physical_package_id, core_id, die_id on kernels >= 5.2)."""
    total = sockets * cores * threads
    base = root / "devices" / "system" / "cpu"
    write(base / "online", cpu_list(list(range(total))))
    write(base / "possible", cpu_list(list(range(total))))
    for s in range(sockets):
        for c in range(cores):
            siblings = [t * sockets * cores + s * cores + c for t in range(threads)]
            for cpu in siblings:
                topo = base / f"cpu{cpu}" / "topology"
                write(topo / "physical_package_id", str(s))
                write(topo / "core_id", str(c))
                if die_id:
                    write(topo / "die_id", "0")
    nodes = numa or [sorted(t * sockets * cores + s * cores + k for t in range(threads) for k in range(cores))
                     for s in range(sockets)]
    nbase = root / "devices" / "system" / "node"
    write(nbase / "online", cpu_list(list(range(len(nodes)))))
    for n, members in enumerate(nodes):
        write(nbase / f"node{n}" / "cpulist", cpu_list(sorted(members)))


def edac(root: Path, mcs: list[list[tuple[str, str, int]]], mc_name: str, mem_type: str, dev_type: str) -> None:
    """mcs[m] = [(label, location, size_mb)] of populated DIMMs of controller m."""
    base = root / "devices" / "system" / "edac" / "mc"
    for m, dimms in enumerate(mcs):
        mc = base / f"mc{m}"
        write(mc / "mc_name", mc_name)
        write(mc / "size_mb", str(sum(d[2] for d in dimms)))
        write(mc / "ce_count", "0")
        write(mc / "ue_count", "0")
        for i, (label, location, size) in enumerate(dimms):
            d = mc / f"dimm{i}"
            write(d / "size", str(size))
            write(d / "dimm_label", label)
            write(d / "dimm_location", location + " ")
            write(d / "dimm_mem_type", mem_type)
            write(d / "dimm_dev_type", dev_type)
            write(d / "dimm_edac_mode", "SECDED")
            write(d / "dimm_ce_count", "0")


def edac_ranks(root: Path, mcs: int, channels: int, chip_selects: list[int], size_mb: int, mc_name: str,
               dev_type: str) -> None:
    """A chip-select based driver's tree (amd64_edac: ``mci->csbased``): one ``rankN`` per populated
    rank, N = chip select x channels + channel (the layer order CHIP_SELECT, CHANNEL), ``size`` one
    rank's MB, label ``mc#<m>csrow#<cs>channel#<ch>``, location ``csrow <cs> channel <ch>``."""
    base = root / "devices" / "system" / "edac" / "mc"
    for m in range(mcs):
        mc = base / f"mc{m}"
        write(mc / "mc_name", mc_name)
        write(mc / "size_mb", str(size_mb * channels * len(chip_selects)))
        write(mc / "ce_count", "0")
        write(mc / "ue_count", "0")
        for cs in chip_selects:
            for ch in range(channels):
                rank = mc / f"rank{cs * channels + ch}"
                write(rank / "size", str(size_mb))
                write(rank / "dimm_label", f"mc#{m}csrow#{cs}channel#{ch}")
                write(rank / "dimm_location", f"csrow {cs} channel {ch} ")
                write(rank / "dimm_mem_type", "Registered-DDR4")
                write(rank / "dimm_dev_type", dev_type)
                write(rank / "dimm_edac_mode", "SECDED")
                write(rank / "dimm_ce_count", "0")


def dmi_record(handle: int, version: str, size_gb: int | None, locator: str, bank: str, *, speed: int, conf: int,
               ranks: int, maker: str, part: str, total_width: int = 72, mem_type: str = "DDR4",
               volts: str = "1.2") -> str:
    """One DMI type 17 record as dmidecode ``version`` ("2.12", "3.2", "3.3", "3.4") prints it (DDR5
    RDIMMs: ``Type: DDR5``, ``Total Width: 80 bits`` = two 32-bit sub-channels with 8 ECC bits each,
    1.1 V)."""
    old = version.startswith("2.")
    unit = "MHz" if old else "MT/s"
    conf_key = "Configured Clock Speed" if version in ("2.12", "3.0", "3.1") else "Configured Memory Speed"
    lines = [f"Handle 0x{handle:04X}, DMI type 17, {40 if old else 84} bytes", "Memory Device",
             "\tArray Handle: 0x0026", "\tError Information Handle: Not Provided"]
    if size_gb is None:
        lines += ["\tTotal Width: Unknown", "\tData Width: Unknown", "\tSize: No Module Installed",
                  "\tForm Factor: DIMM", "\tSet: None", f"\tLocator: {locator}", f"\tBank Locator: {bank}",
                  "\tType: Unknown", "\tType Detail: None", "\tSpeed: Unknown", "\tManufacturer: NO DIMM",
                  "\tSerial Number: NO DIMM", "\tAsset Tag: NO DIMM", "\tPart Number: NO DIMM", "\tRank: Unknown",
                  f"\t{conf_key}: Unknown"]
    else:
        size = f"{size_gb * 1024} MB" if old else f"{size_gb} GB"
        lines += [f"\tTotal Width: {total_width} bits", "\tData Width: 64 bits", f"\tSize: {size}",
                  "\tForm Factor: DIMM", "\tSet: None", f"\tLocator: {locator}", f"\tBank Locator: {bank}",
                  f"\tType: {mem_type}", "\tType Detail: Synchronous Registered (Buffered)", f"\tSpeed: {speed} {unit}",
                  f"\tManufacturer: {maker}", f"\tSerial Number: {0x1A2B3C00 + handle:08X}",
                  f"\tAsset Tag: {locator}_AssetTag", f"\tPart Number: {part:<20}", f"\tRank: {ranks}",
                  f"\t{conf_key}: {conf} {unit}"]
        if not old:
            lines += [f"\tMinimum Voltage: {volts} V", f"\tMaximum Voltage: {volts} V", f"\tConfigured Voltage: {volts} V"]
    return "\n".join(lines) + "\n"


def processor_record(handle: int, socket: int, version: str, maker: str, signature: str, cores: int) -> str:
    """One populated DMI type 4 (Processor Information) record as dmidecode 3.x prints it."""
    lines = [f"Handle 0x{handle:04X}, DMI type 4, 48 bytes", "Processor Information",
             f"\tSocket Designation: CPU{socket}", "\tType: Central Processor", f"\tManufacturer: {maker}",
             f"\tSignature: {signature}", f"\tVersion: {version}", "\tStatus: Populated, Enabled",
             f"\tCore Count: {cores}", f"\tCore Enabled: {cores}", f"\tThread Count: {2 * cores}"]
    return "\n".join(lines) + "\n"


def powercap(root: Path, packages: list[tuple[str, list[str]]]) -> None:
    """``class/powercap`` as intel_rapl_msr registers it (see tests/sources/powercap_trees.py): package zones
    ``intel-rapl:<i>`` in registration order with their subzones, real directories under
    ``devices/virtual/powercap/intel-rapl`` and a symlink per zone in ``class/powercap``."""
    control = root / "devices" / "virtual" / "powercap" / "intel-rapl"
    links = root / "class" / "powercap"
    links.mkdir(parents=True)
    for i, (name, subzones) in enumerate(packages):
        zones = [(f"intel-rapl:{i:x}", name)] + [(f"intel-rapl:{i:x}/intel-rapl:{i:x}:{j:x}", sub)
                                                 for j, sub in enumerate(subzones)]
        for rel, zone_name in zones:
            for key, value in (("name", zone_name), ("energy_uj", 1000), ("max_energy_range_uj", 262143328850)):
                write(control / rel / key, str(value))
            (links / rel.split("/")[-1]).symlink_to(f"../../devices/virtual/powercap/intel-rapl/{rel}")


def dmidecode_file(path: Path, version: str, records: list[str]) -> None:
    head = f"# dmidecode {version}\n"
    head += "SMBIOS 2.8 present.\n" if version.startswith("2.") else "Getting SMBIOS data from sysfs.\nSMBIOS 3.2.0 present.\n"
    path.write_text(head + "\n" + "\n".join(records))


def haswell(dest: Path) -> None:
    """Taurus Haswell-EP: 2 x E5-2680 v3 (12 cores, HT), 4 channels/socket, 1 DPC, 8 x M393A1G43DB0-CPB."""
    root = dest / "haswell-ep-taurus"
    cpus(root / "sys", 2, 12, 2, die_id=False)
    edac(root / "sys", [[(f"CPU_SrcID#{s}_Ha#0_Chan#{c}_DIMM#0", f"channel {c} slot 0", 8192) for c in range(4)]
                        for s in range(2)], "Haswell SrcID#0_Ha#0", "Registered-DDR4", "x8")
    recs = []
    h = 0x30
    for s in range(2):
        for c, letter in enumerate("ABCD"):
            recs.append(dmi_record(h, "2.12", 8, f"P{s + 1}-DIMM{letter}1", f"P{s}_Node{s}_Channel{c}_Dimm0",
                                   speed=2133, conf=2133, ranks=2, maker="Samsung", part="M393A1G43DB0-CPB"))
            h += 2
    dmidecode_file(root / "dmidecode.txt", "2.12", recs)


def skylake(dest: Path, name: str, numa: list[list[int]] | None) -> None:
    """2 x Xeon Gold 6148 (20 cores, HT), 6 channels/socket, 2 slots/channel, 1 populated:
    12 x Samsung M393A2K43BB1-CTD (16 GB 2Rx8, 8 Gb B-die, DDR4-2666)."""
    root = dest / name
    cpus(root / "sys", 2, 20, 2, die_id=False, numa=numa)
    mcs = [[(f"CPU_SrcID#{s}_MC#{m}_Chan#{c}_DIMM#0", f"channel {c} slot 0", 16384) for c in range(3)]
           for s in range(2) for m in range(2)]
    edac(root / "sys", mcs, "Intel_Skylake_SP", "Registered-DDR4", "x8")
    recs = []
    h = 0x40
    for s in range(2):
        for letter in "ABCDEF":
            for slot in (1, 2):
                size = 16 if slot == 1 else None
                recs.append(dmi_record(h, "3.2", size, f"CPU{s + 1}_DIMM_{letter}{slot}", f"NODE {s + 1}", speed=2666,
                                       conf=2666, ranks=2, maker="Samsung", part="M393A2K43BB1-CTD"))
                h += 1
    dmidecode_file(root / "dmidecode.txt", "3.2", recs)


def icelake(dest: Path) -> None:
    """2 x Xeon Gold 6330 (28 cores, HT), 8 channels/socket, 2 DPC: 32 x Micron MTA36ASF4G72PZ-3G2R1
    (32 GB 2Rx4, 8 Gb dies, DDR4-3200 run at 2933)."""
    root = dest / "icelake-sp-2dpc"
    cpus(root / "sys", 2, 28, 2, die_id=True)
    mcs = [[(f"CPU_SrcID#{s}_MC#{m}_Chan#{c}_DIMM#{d}", f"channel {c} slot {d}", 32768) for c in range(2) for d in range(2)]
           for s in range(2) for m in range(4)]
    edac(root / "sys", mcs, "Intel_10nm_Icelake-SP", "Registered-DDR4", "x4")
    recs = []
    h = 0x50
    for s in range(2):
        for c, letter in enumerate("ABCDEFGH"):
            for d in range(2):
                recs.append(dmi_record(h, "3.3", 32, f"P{s + 1}-DIMM{letter}{d + 1}", f"P{s}_Node{s}_Channel{c}_Dimm{d}",
                                       speed=3200, conf=2933, ranks=2, maker="Micron Technology",
                                       part="MTA36ASF4G72PZ-3G2R1"))
                h += 1
    dmidecode_file(root / "dmidecode.txt", "3.3", recs)


def epyc(dest: Path) -> None:
    """2 x AMD EPYC 7302 (16 cores, SMT), NPS1, 8 channels/socket, 1 DPC, no EDAC driver loaded:
    16 x Samsung M393A4K40DB2-CVF (32 GB 2Rx4, 8 Gb D-die, DDR4-2933)."""
    root = dest / "epyc-rome-8ch"
    cpus(root / "sys", 2, 16, 2, die_id=True)
    recs = []
    h = 0x60
    for s in range(2):
        for letter in "ABCDEFGH":
            recs.append(dmi_record(h, "3.2", 32, "DIMM 0", f"P{s} CHANNEL {letter}", speed=2933, conf=2933,
                                   ranks=2, maker="Samsung", part="M393A4K40DB2-CVF"))
            h += 1
    dmidecode_file(root / "dmidecode.txt", "3.2", recs)


def one_socket(dest: Path) -> None:
    """1 x Xeon Silver 4116 (12 cores, HT), 6 channels, 1 DPC: 6 x SK hynix HMA82GR7AFR8N-VK (16 GB 2Rx8, 8 Gb A-die,
    DDR4-2666 run at 2400)."""
    root = dest / "one-socket-skylake"
    cpus(root / "sys", 1, 12, 2, die_id=True)
    edac(root / "sys", [[(f"CPU_SrcID#0_MC#{m}_Chan#{c}_DIMM#0", f"channel {c} slot 0", 16384) for c in range(3)]
                        for m in range(2)], "Intel_Skylake_SP", "Registered-DDR4", "x8")
    recs = []
    h = 0x70
    for c, letter in enumerate("ABCDEF"):
        recs.append(dmi_record(h, "3.3", 16, f"P1-DIMM{letter}1", f"P0_Node0_Channel{c}_Dimm0", speed=2666, conf=2400,
                               ranks=2, maker="SK Hynix", part="HMA82GR7AFR8N-VK"))
        h += 1
    dmidecode_file(root / "dmidecode.txt", "3.3", recs)


def haswell_cod(dest: Path) -> None:
    """2 x Xeon E5-2695 v3 (14 cores, HT), Cluster-on-Die: two NUMA nodes of 7 cores per socket (the
    page's likwid domains C0-C3); sb_edac: one controller per home agent, two channels each; x4 DIMMs."""
    root = dest / "haswell-ep-x10drl-cod"
    cod = [[c + t * 28 for t in range(2) for c in range(d * 7, d * 7 + 7)] for d in range(4)]
    cpus(root / "sys", 2, 14, 2, die_id=False, numa=cod)
    mcs = [[(f"CPU_SrcID#{s}_Ha#{h}_Chan#{c}_DIMM#0", f"channel {c} slot 0", 8192) for c in range(2)]
           for s in range(2) for h in range(2)]
    edac(root / "sys", mcs, "Haswell SrcID#0_Ha#0", "Registered-DDR4", "x4")
    shutil.copyfile(CAPTURES / "supermicro-x10drl-i-haswell-ep.txt", root / "dmidecode.txt")


def skylake_x11ddw(dest: Path) -> None:
    """2 x Xeon Gold 6148 (20 cores, HT) with SNC2; skx_edac: 2 controllers x 3 channels per socket, one
    8 GB 2Rx8 DIMM each."""
    root = dest / "skylake-sp-x11ddw-snc2"
    snc = [[c + t * 40 for t in range(2) for c in range(s * 20 + h * 10, s * 20 + h * 10 + 10)]
           for s in range(2) for h in range(2)]
    cpus(root / "sys", 2, 20, 2, die_id=False, numa=snc)
    mcs = [[(f"CPU_SrcID#{s}_MC#{m}_Chan#{c}_DIMM#0", f"channel {c} slot 0", 8192) for c in range(3)]
           for s in range(2) for m in range(2)]
    edac(root / "sys", mcs, "Intel_Skylake_SP", "Registered-DDR4", "x8")
    shutil.copyfile(CAPTURES / "supermicro-x11ddw-l-skylake-sp.txt", root / "dmidecode.txt")


def epyc_ranks(dest: Path) -> None:
    """The EPYC 7302 node with amd64_edac loaded (one controller per socket, 8 UMC channels) and no
    dmidecode: 16 x 32 GB 2Rx4 DIMMs show as 32 rank directories of 16 GB (chip selects 0 and 1)."""
    root = dest / "epyc-rome-amd64-edac"
    cpus(root / "sys", 2, 16, 2, die_id=True)
    edac_ranks(root / "sys", 2, 8, [0, 1], 16384, "F17h_M30h", "x4")


def sapphire_rapids(dest: Path) -> None:
    """2 x Xeon Platinum 8480+ (56 cores, HT; family 6 model 143 = INTEL_SAPPHIRERAPIDS_X), 8 DDR5 channels per
    socket (4 controllers x 2), 2 slots per channel, 1 populated: 16 x Micron MTC20F2085S1RC48BA1 (32 GB 2Rx8
    DDR5-4800 RDIMM, 16 Gb dies, 20 devices = 2 ranks x 2 sub-channels x (4 + 1 ECC) x8). Slot names as
    ASUS/Gigabyte AMI BIOSes print them (``CPU1_DIMM_A1``, bank ``NODE 1``); RAPL: one ``dram`` zone per
    package (``rapl_defaults_spr_server`` of intel_rapl_common.c)."""
    root = dest / "sapphire-rapids-2s"
    cpus(root / "sys", 2, 56, 2, die_id=True)
    powercap(root / "sys", [("package-0", ["dram"]), ("package-1", ["dram"])])
    recs = [processor_record(0x20 + s, s, "Intel(R) Xeon(R) Platinum 8480+", "Intel(R) Corporation",
                             "Type 0, Family 6, Model 143, Stepping 8", 56) for s in range(2)]
    h = 0x80
    for s in range(2):
        for letter in "ABCDEFGH":
            for slot in (1, 2):
                recs.append(dmi_record(h, "3.4", 32 if slot == 1 else None, f"CPU{s + 1}_DIMM_{letter}{slot}",
                                       f"NODE {s + 1}", speed=4800, conf=4800, ranks=2, maker="Micron Technology",
                                       part="MTC20F2085S1RC48BA1", total_width=80, mem_type="DDR5", volts="1.1"))
                h += 1
    dmidecode_file(root / "dmidecode.txt", "3.4", recs)


def genoa(dest: Path) -> None:
    """2 x AMD EPYC 9654 (96 cores, SMT; family 25 model 17), NPS1, 12 DDR5 channels per socket, 1 DPC, no
    EDAC driver loaded: 24 x Micron MTC40F2046S1RC48BA1 (64 GB 2Rx4 DDR5-4800 RDIMM, 16 Gb dies). Slot names
    as AMD reference-BIOS boards print them (``DIMM 0`` in bank ``P0 CHANNEL A`` .. ``L``, as the Rome
    fixture); RAPL: package zones with a ``core`` subzone and no ``dram`` zone (intel_rapl_msr on AMD:
    package and core energy only)."""
    root = dest / "genoa-2s"
    cpus(root / "sys", 2, 96, 2, die_id=True)
    powercap(root / "sys", [("package-0", ["core"]), ("package-1", ["core"])])
    recs = [processor_record(0x30 + s, s, "AMD EPYC 9654 96-Core Processor", "Advanced Micro Devices, Inc.",
                             "Family 25, Model 17, Stepping 1", 96) for s in range(2)]
    h = 0x90
    for s in range(2):
        for letter in "ABCDEFGHIJKL":
            recs.append(dmi_record(h, "3.4", 64, "DIMM 0", f"P{s} CHANNEL {letter}", speed=4800, conf=4800,
                                   ranks=2, maker="Micron Technology", part="MTC40F2046S1RC48BA1", total_width=80,
                                   mem_type="DDR5", volts="1.1"))
            h += 1
    dmidecode_file(root / "dmidecode.txt", "3.4", recs)


def build(dest: Path) -> Path:
    """Write every node fixture (``dest/<node>/sys`` and ``dest/<node>/dmidecode.txt``); returns ``dest``."""
    haswell(dest)
    skylake(dest, "skylake-sp", None)
    # SNC2: each socket's 20 cores split into two NUMA nodes of 10 (with their hyper-threads)
    snc = [[c + t * 40 for t in range(2) for c in range(s * 20 + h * 10, s * 20 + h * 10 + 10)]
           for s in range(2) for h in range(2)]
    skylake(dest, "skylake-sp-snc2", snc)
    icelake(dest)
    epyc(dest)
    one_socket(dest)
    haswell_cod(dest)
    skylake_x11ddw(dest)
    epyc_ranks(dest)
    sapphire_rapids(dest)
    genoa(dest)
    return dest


if __name__ == "__main__":
    build(Path(sys.argv[1]))
