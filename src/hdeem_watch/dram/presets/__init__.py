"""Built-in DDR4 memspecs (DRAMPower JSON files in this directory) and where each number comes from.

Every preset's timings come from one named source (:attr:`PresetInfo.timings`, tested value for value
against excerpts of it in tests/dram/sources/): a DRAMPower memspec, a DRAMsim3 config file, or
JESD79-4 itself. Where a DRAMsim3 file is the source, every timing the file gives is taken in its
cycles, and the fields it has not are derived the same way for every such preset: ``tCK`` =
the bin's JESD79-4 tCK (0.9375, 0.833, 0.75, 0.682, 0.625 ns; the files round it to 10 ps), ``REFI`` = 7.8 us in those clocks, ``RL`` = ``CL``,
``WL`` = ``CWL``, ``RC`` = ``RAS + RP``, ``XPDLL`` = 24 ns and ``XSDLL`` = tDLLK (JESD79-4). The
load-time check also holds every timing against JESD79-4's minimums
(:func:`hdeem_watch.dram.memspec_check.timing_violations`).

Every preset describes one channel of dual-rank x8 modules with 9 devices per rank (2Rx8 ECC RDIMM,
the common HPC configuration) unless said otherwise (the x4 preset: 2Rx4, 18 devices per rank); :func:`hdeem_watch.node.memspec_choice.for_dimm`
re-shapes a preset to the ranks and devices of a detected DIMM. Every preset passes the physical
check of :mod:`hdeem_watch.dram.memspec_check` (every per-command energy >= 0). Currents are
amperes per device, as DRAMPower wants them.

``ddr4-2133-x8-4gb`` (``ddr4-2133-x8-4gb.json``)
    A byte-for-byte copy of ``reference/drampower/memspecs/ddr4_2133_x8_2r_8dev.json``, the device
    the DRAMPower v6.2 reference outputs were computed with: DDR4-2133 (tCK 0.9375 ns, 15-15-15,
    RAS 36, RC 51, RFC1 278, REFI 8320 cycles), 4 Gb x8, 16 banks in 4 bank groups, 32768 rows x
    1024 columns, 2 ranks x 8 devices. Currents per device (the reference README): the mid-point of
    the Micron 4 Gb x8 rev-A DDR4-1866 and DDR4-2400 memspecs that DRAMPower 4.1 shipped (IDD0 58.5,
    IDD2N 36.0, IDD3N 41.75, IDD4R 171.0, IDD4W 151.875, IDD5B 118, IDD6N 20.25, IDD2P 17,
    IDD3P 22.5, IPP0 4.05, IPP6N 2.6 mA, other IPP 0); VDD 1.2, VPP 2.5, VDDQ 1.2 V. Interface
    impedances are DRAMPower's test placeholders (1 MOhm, 1 pJ), not a real board. An interpolation,
    not a datasheet: kept as the DRAMPower reference device.

``samsung-m393a1g43db0-cpb`` (``samsung-m393a1g43db0-cpb.json``)
    Samsung M393A1G43DB0-CPB, 8 GB DDR4-2133P (15-15-15) registered ECC DIMM, 2 ranks x 9 x8 4 Gb
    D-die (K4A4G085WD) devices, as on the Haswell-EP nodes (Taurus) of the seed paper.

    - Geometry and timings: the module's organisation (1G x 72, 2Rx8, 4 Gb dies) with the JEDEC
      4 Gb x8 addressing and the DDR4-2133P speed bin, identical to ``ddr4-2133-x8-4gb``.
    - Module figures used (Samsung module datasheet, quoted second-hand in DESIGN.md section 4):
      IDD0 1120, IDD2N 1040, IDD3N 1540, IDD4R 1750, IDD4W 1590 mA per module.
    - Conversion to per device: Samsung's own definition of which rank is in which state was not
      found in a public source, nor the K4A4G085WD die's IDD table. We therefore apply the definition
      Micron prints for its DDR4 dual-rank modules whose figures are "computed from values specified
      in the component data sheet" (e.g. MTA18ASF2G72HZ, asf18c2gx72hz.pdf Rev. F, Table 15 notes:
      operating currents IDD0/IDD4R/IDD4W/IDD5B = "one module rank in the active IDD, the other rank
      in IDD2P"; standby currents IDD2N/IDD3N/IDD2P/IDD3P/IDD6N = "all ranks in this condition"),
      and no register (RCD) share, since such computed figures contain none:
      IDD2N = 1040 / 18 = 57.78, IDD3N = 1540 / 18 = 85.56,
      IDD0 = 1120 / 9 - IDD2P = 107.44, IDD4R = 1750 / 9 - IDD2P = 177.44,
      IDD4W = 1590 / 9 - IDD2P = 159.67 mA, with IDD2P = 17 mA (the reference device's, below).
      Were the RCD's current part of the module figures, every per-device current would be lower
      by RCD / 18 (standby) resp. RCD / 9 (operating); the calibration absorbs such a shift.
      The former conversion (every figure / 18) put IDD0 (62.2) below IDD3N (85.6): a negative
      activation energy.
    - IDD5B, IDD6N, IDD2P, IDD3P, every IPP, VDD/VPP/VDDQ and the interface section: no public
      per-device figure for this module was available to us, so the reference device's values
      (``ddr4-2133-x8-4gb``) are used unchanged.

``micron-4gb-x8-ddr4-2400-a`` (``micron-4gb-x8-ddr4-2400-a.json``)
    Micron 4 Gb x8 die revision A (MT40A512M8), DDR4-2400, as DRAMPower's memspec
    ``MICRON_4Gb_DDR4-2400_8bit_A`` gives it (tukl-msd/DRAMPower ``memspecs/``; Micron 4Gb DDR4
    datasheet): tCK 0.833 ns, RCD = RP = RL = 16, RAS 39, RC 55, RFC1/2/4 313/192/132 (260/160/110
    ns), FAW 26, RRD_S/L 4/6, CCD_S/L 4/6, WTR_S/L 3/9, WR 18, RTP 12, WL 16; IDD0 60.75, IPP0 4.05,
    IDD2N 38.25, IDD2P 17, IDD3N 44, IDD3P 22.5, IDD4R 184.5, IDD4W 168.75, IDD5B 118, IDD6N 20.25,
    IPP6N 2.6 mA; IPPs the file does not give are 0. One change: REFI 9360 cycles = 7.8 us, the
    JEDEC interval for 0-85 C (the file has 4680 = 3.9 us, the extended-temperature rate).

``micron-8gb-x8-ddr4-2400-b`` (``micron-8gb-x8-ddr4-2400-b.json``)
    Micron 8 Gb x8 die revision B (MT40A1G8), DDR4-2400. Currents: Micron's MTA18ASF2G72HZ
    (16 GB 2Rx8 ECC, 18 of these dies) datasheet asf18c2gx72hz.pdf Rev. F, Table 15, converted back
    to per device by the table's own notes (see the Samsung entry): IDD2N 612/18 = 34, IDD2P
    450/18 = 25, IDD3N 774/18 = 43, IDD3P 666/18 = 37, IDD6N 540/18 = 30, IPP3N 54/18 = 3,
    IDD0 = 657/9 - 25 = 48, IDD4R = 1440/9 - 25 = 135, IDD4W = 1332/9 - 25 = 123,
    IDD5B = 2475/9 - 25 = 250, IPP0 = 54/9 - 3 = 3, IPP5B = 279/9 - 3 = 28 mA. The other IPPs
    (IPP2N, IPP2P, IPP3P, IPP4R, IPP4W, IPP6N) are set to IPP3N = 3 mA: Micron's 8 Gb datasheet
    states the IPP3N limit applies to all IDD2x, IDD3x, IDD4x (and, in the 16 Gb one, IDD6x)
    conditions. Timings: DRAMsim3's ``configs/DDR4_8Gb_x8_2400.ini`` (the same die and bin), by the
    rules above: 17-17-17 (the module's -2G3 grade is DDR4-2400 CL17), RAS 39, RC 56, CWL 12, RTP 9,
    FAW 26, the 8 Gb refresh times tRFC1/2/4 = 420/312/192 cycles, XS 432, XPDLL 29, XSDLL 768.
    (Until issue 29 the preset carried the 4 Gb rev-A DRAMPower timings: WL 16, RTP 12, XPDLL 325,
    XSDLL 512, RCD/RP 16.)

``micron-8gb-x8-ddr4-3200-g`` (``micron-8gb-x8-ddr4-3200-g.json``)
    Micron 8 Gb x8 die revision G (MT40A1G8, -062E, DDR4-3200AA), as DRAMPower's memspec
    ``MICRON_8Gb_DDR4-3200_8bit_G.xml`` gives it (datasheet ``8gb_ddr4_sdram.pdf``): tCK 0.625 ns,
    RCD = RP = RL = 22, RAS 52, RC 74, RFC1 560 (350 ns), REFI 12480 (7.8 us), FAW 34, RRD_S/L 4/8,
    CCD_S/L 4/8, WTR_S/L 4/12, WR 24, RTP 12, WL 16, XS 576, XSDLL 1024, CKE 8, CKESR 9; IDD0 57,
    IPP0 3, IDD2N 37, IDD2P 25, IDD3N 56, IPP3N 3, IDD3P 43, IDD4R 168, IDD4W 155, IDD6N 31,
    IPP6N 5 mA; the file's ``idd5`` 66 mA / ``idd52`` 5 mA are used as IDD5B / IPP5B (the file does
    not say whether they are the burst IDD5B or the distributed IDD5R: refresh energy may be low).
    RFC2/RFC4 = 260/160 ns (416/256 cycles, the JEDEC 8 Gb values; unused with RefMode 1). IPP2N,
    IPP2P, IPP3P, IPP4R, IPP4W = IPP3N (the datasheet's IPP3N note, see above).

``micron-8gb-x4-ddr4-2400-b`` (``micron-8gb-x4-ddr4-2400-b.json``)
    Micron 8 Gb x4 die (MT40A2G4, the x4 organisation of the MT40A1G8 die above), DDR4-2400 (-083E),
    one channel of 2Rx4 ECC RDIMMs (2 ranks x 18 devices). Currents: the Micron "8Gb: x4, x8, x16
    DDR4 SDRAM" datasheet's x4 column for DDR4-2400 as gem5 quotes it (gem5/gem5
    ``src/python/gem5/components/memory/dram_interfaces/ddr4.py``, class ``DDR4_2400_16x4``, "timings
    based on a DDR4-2400 8 Gbit datasheet (Micron MT40A2G4)", "Current values from datasheet"):
    IDD0 43, IPP0 3, IDD2N 34, IDD2P 25, IDD3N 38, IPP3N 3, IDD3P 32, IDD4R 110, IDD4W 103,
    IDD5 250 (used as IDD5B), IDD6 30 mA; VDD 1.2, VPP 2.5 V. The same file's ``DDR4_2400_8x8``
    (MT40A1G8) currents are exactly the per-device figures of ``micron-8gb-x8-ddr4-2400-b`` above
    (IDD0 48, IDD3N 43, IDD4R 135, IDD4W 123, IDD3P 37, the rest shared), which the module datasheet
    gave independently. The source has no IPP5B for x4: the x8 die's 28 mA is used (IPP0 and IPP3N
    are equal for x4 and x8 there); IPP2N, IPP2P, IPP3P, IPP4R, IPP4W, IPP6N = IPP3N as above.
    Geometry: 16 banks in 4 bank groups, 131072 rows x 1024 columns (512 B page). Timings: DRAMsim3's
    ``configs/DDR4_8Gb_x4_2400.ini`` by the rules above: those of the x8 preset except FAW = 16
    cycles (13.3 ns: tFAW of a 512 B page is max(16 nCK, 13 ns); gem5 ``tXAW`` 13.328 ns).

``micron-8gb-x16-ddr4-2666-b`` (``micron-8gb-x16-ddr4-2666-b.json``)
    Micron 8 Gb x16 die revision B (MT40A512M16), DDR4-2666, one channel of single-rank x64 modules
    (1 rank x 4 devices, no ECC; laptops, desktops and x16-based UDIMM/SODIMM nodes). Currents:
    Micron's MTA4ATF51264AZ (4 GB 1Rx16 UDIMM, 4 of these dies) datasheet atf4c512x64az.pdf Rev. B
    8/16, Table 13 ("Die Revision B", "computed from values specified in the 8Gb (512 Meg x 16)
    component data sheet"), column 2666; with one rank every device is in the measured state, so per
    device = module / 4: IDD0 340/4 = 85, IPP0 16/4 = 4, IDD2N 140/4 = 35, IDD2P 100/4 = 25,
    IDD3N 200/4 = 50, IPP3N 12/4 = 3, IDD3P 172/4 = 43, IDD4R 1052/4 = 263, IDD4W 976/4 = 244,
    IDD5B 1120/4 = 280, IPP5B 112/4 = 28, IDD6N 120/4 = 30 mA. The table's 2400 column divided the
    same way is exactly gem5's ``DDR4_2400_4x16`` (MT40A512M16: IDD0 80, IDD2N 34, IDD3N 47, IDD4R 243,
    IDD4W 228, IDD5 280, IDD3P 41, IPP0 4 mA), a check of the conversion. IPP2N, IPP2P, IPP3P,
    IPP4R, IPP4W, IPP6N = IPP3N: the 8 Gb/16 Gb die datasheets' note "IPP3N test and limit is
    applicable for all IDD2x, IDD3x, IDD4x, IDD6x and IDD8 conditions". Geometry (x16, 8 Gb): 8 banks
    in 2 bank groups, 65536 rows x 1024 columns (2 KB page). Timings: the module's -2G6 grade is the
    component's -075 (Micron's module-to-component speed-grade table, e.g. asf18c1gx72az.pdf Rev. F
    Table 12), DDR4-2666 CL19: tCK 0.75 ns,
    RL = RCD = RP = 19 (14.25 ns), RAS 43 (32 ns), RC 62, WL 14 (CWL 14); the one source is
    JESD79-4: its values for a 2 KB page at 2666 in cycles of 0.75 ns, by JEDEC's rounding: RRD_S 8 (5.3 ns), RRD_L 9 (6.4 ns),
    FAW 40 (30 ns), CCD_L 7 (5 ns), WTR_S/L 4/10 (2.5/7.5 ns), WR 20 (15 ns), RTP 10 (7.5 ns), XP 8
    (6 ns), XPDLL 32 (24 ns), CKE 7 (5 ns), CKESR 8, XSDLL 854 (tDLLK at 2666); the 8 Gb refresh
    times RFC1/2/4 467/347/214 (350/260/160 ns), XS 480 (RFC1 + 10 ns), REFI 10400 (7.8 us).
    DRAMsim3's ``DDR4_8Gb_x16_2666.ini`` has RRD_S 7: 5.3 ns is 7.07 clocks, which JEDEC's rounding
    (0.974 correction) makes 8; the preset keeps JESD79-4's 8.

``micron-8gb-x8-ddr4-2666``, ``micron-8gb-x8-ddr4-2933``, ``micron-8gb-x4-ddr4-2666``, ``micron-8gb-x4-ddr4-2933``, ``micron-8gb-x4-ddr4-3200``
    Micron 8 Gb DDR4 dies (MT40A1G8 x8, MT40A2G4 x4) at the DDR4-2666, -2933 and -3200 speed bins,
    one channel of 2Rx8 (9 devices per rank) or 2Rx4 (18 devices per rank) ECC RDIMMs. Currents:
    the Micron "8Gb: x4, x8, x16 DDR4 SDRAM" datasheet (8gb_ddr4_sdram.pdf) columns as DRAMsim3
    quotes them (umd-memsys/DRAMsim3 ``configs/DDR4_8Gb_x{4,8}_{2666,2933,3200}.ini``; the file
    ``DDR4_8Gb_x8_2400.ini`` of the same set named its part, "Micron MT40A1G8PM-083E", until the
    comment was dropped in commit 7bf30ed of 2018-05-07). The set is checked against the sources
    above: its x8 2400 currents are the per-device figures of Micron's MTA18ASF2G72HZ module table
    (``micron-8gb-x8-ddr4-2400-b``, IDD6x = 30 mA in every version of the file; 31 mA is the
    IDD6N of DRAMPower's rev-G 3200 memspec), its x4 2400
    currents are gem5's MT40A2G4 ones (``micron-8gb-x4-ddr4-2400-b``), and its x16 2666 currents
    are exactly Micron's MTA4ATF51264AZ table divided by its 4 devices (``micron-8gb-x16-ddr4-2666-b``).
    Per device, mA (IDD0, IDD2N, IDD2P, IDD3N, IDD3P, IDD4R, IDD4W, IDD5B, IDD6N; IPP0 3 for all):

    - x8 2666: 51, 35, 25, 46, 39, 146, 132, 250, 30;  x8 2933: 54, 36, 25, 49, 41, 157, 141, 250, 30
    - x4 2666: 46, 35, 25, 41, 34, 121, 112, 250, 30;  x4 2933: 49, 36, 25, 44, 36, 132, 121, 250, 30
    - x4 3200: 52, 37, 25, 47, 38, 143, 130, 250, 30

    (DRAMsim3's x8 3200 file, IDD3N 52 and IDD4W 150 mA, differs from the DRAMPower rev-G memspec of
    ``micron-8gb-x8-ddr4-3200-g``, IDD3N 56 and IDD4W 155: another datasheet revision; that preset is
    kept.) The files give IDD5 as the refresh current, used as IDD5B. Not in them: IPP3N (3 mA) and
    IPP5B (28 mA) are the 8 Gb x8 rev-B module table's (above); the other IPPs = IPP3N (the
    datasheet's IPP3N note). Timings: each file's, by the rules above (2666 19-19-19 at 0.75 ns,
    2933 21-21-21 at 0.682 ns, 3200 22-22-22 at 0.625 ns; RAS 43/47/52, RRD_L 7/8/8 (4.9 ns),
    FAW x8 28/31 (21 ns) and x4 16 (16 nCK), WR 20/22/24, RTP 10/11/12, CCD_L 7/8/8, WTR_S/L 4 and
    10/11/12, CKE 7/8/8, XP 8/9/10, 8 Gb RFC1/2/4 350/260/160 ns, XS = RFC1 + 10 ns, CWL 14/16/16;
    XSDLL = tDLLK 854/940/1024 nCK).
    Geometry: 16 banks in 4 bank groups, 65536 (x8) or 131072 (x4) rows of 1024 columns.

``micron-4gb-x4-ddr4-2133``, ``micron-4gb-x4-ddr4-2400``
    Micron 4 Gb x4 dies (MT40A1G4) at DDR4-2133 and -2400, one channel of 2Rx4 ECC RDIMMs (2 ranks
    x 18 devices; the 8 GB 1Rx4 / 16 GB 2Rx4 modules of Haswell- and Broadwell-era nodes). Currents:
    the Micron 4 Gb DDR4 datasheet columns as DRAMsim3 quotes them (``configs/DDR4_4Gb_x4_2133.ini``,
    ``DDR4_4Gb_x4_2400.ini``), per device, mA: 2133: IDD0 55, IDD2N 42, IDD2P 27, IDD3N 55, IDD3P 40,
    IDD4R 135, IDD4W 155, IDD5B 170, IDD6N 20, IPP0 3; 2400: 60, 45, 29, 60, 40, 145, 175, 175, 20,
    IPP0 3. The files give x4 the same figures as their x8 files, and the x8 ones are checked by
    Micron's MTA18ASF1G72AZ module datasheet (asf18c1gx72az.pdf Rev. F, Table 13, die revision B,
    2Rx8 of MT40A512M8) converted by its notes: IDD2N 756/18 = 42 and 810/18 = 45, IDD0 738/9 - 27
    = 55 and 801/9 - 29 = 60 mA at 2133 and 2400. The other IPPs are not in the files: 0, as in
    DRAMPower's 4 Gb memspecs. Timings: the files' cycles (2133 16-16-16 at 0.9375 ns, 2400 17-17-17
    at 0.833 ns; RAS 36/39, RFC1/2/4 278/171/118 and 312/192/132 (4 Gb: 260/160/110 ns), RRD_L 6,
    FAW 16, WR 16/18, RTP 8/9, CCD_L 6, WTR_S/L 3 and 8/9, CKE 6, XP 7/8, XS 289/324, CWL 11/12),
    by the rules above (XSDLL 597/768 nCK).
    Geometry: 16 banks in 4 bank groups, 65536 rows x 1024 columns.

Not (yet) in the library, for want of a complete public per-die IDD table (a partial one exists:
Micron's MT40A1G16 rev D datasheet gives IDD0, IPP0, IDD1, IDD2N, IDD2NT and IDD2P only; the stored
copy of SK hynix's H5ANAG4/8/6NCJR 16 Gb datasheet stops after the first rows as well; DRAMSys ships
DDR4 memspecs of 4 Gb x8, DRAMPower's history 4 Gb x8 and the 8 Gb x8/x16 rev-G 3200 ones (one used
here), gem5 8 Gb DDR4-2400 only, DRAMsim3 4 and 8 Gb dies only; Ramulator 2's DDR4 carried an
unattributed "Default" current preset (IDD0 60, IDD2N 50, IDD3N 55 mA ...) from commit 6c0cd42 of
2024-05-23 until 38c51d4 of 2026-06-27): 16 Gb dies. The node's choice then takes the nearest preset
as the calibration's prior and says so (:mod:`hdeem_watch.node.memspec_choice`); bring your own
(``--memspec FILE``; docs/your-node.md) or let the calibration fit the currents.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class PresetInfo:
    """What a preset describes, for choosing one for a DIMM.

    Attributes:
        file: the JSON file in this directory.
        speed_mts: data rate (MT/s).
        die_gbit: die density (Gbit).
        width: device data width (4, 8 or 16).
        vendor: die (or module) manufacturer.
        die: die name and revision.
        source: the datasheet the currents come from (one line).
        timings: the one named source of every timing (see the module docstring for the rules that
            derive what a DRAMsim3 file does not give).
    """

    file: str
    speed_mts: int
    die_gbit: int
    width: int
    vendor: str
    die: str
    source: str
    timings: str = ""


#: Preset name -> what it describes.
PRESET_INFO: dict[str, PresetInfo] = {
    "ddr4-2133-x8-4gb": PresetInfo("ddr4-2133-x8-4gb.json", 2133, 4, 8, "Micron", "4Gb x8 rev A (interpolated)",
                                   "DRAMPower 4.1 Micron 4Gb x8 rev A 1866/2400 memspecs, mid-point",
        timings="DRAMPower reference memspec ddr4_2133_x8_2r_8dev.json"),
    "samsung-m393a1g43db0-cpb": PresetInfo("samsung-m393a1g43db0-cpb.json", 2133, 4, 8, "Samsung",
                                           "K4A4G085WD (4Gb x8 D-die)",
                                           "Samsung M393A1G43DB0 module IDDs, Micron's dual-rank module definition",
        timings="DRAMPower reference memspec ddr4_2133_x8_2r_8dev.json"),
    "micron-4gb-x8-ddr4-2400-a": PresetInfo("micron-4gb-x8-ddr4-2400-a.json", 2400, 4, 8, "Micron",
                                            "MT40A512M8 (4Gb x8 rev A)",
                                            "DRAMPower memspec MICRON_4Gb_DDR4-2400_8bit_A",
        timings="DRAMPower memspec MICRON_4Gb_DDR4-2400_8bit_A"),
    "micron-8gb-x8-ddr4-2400-b": PresetInfo("micron-8gb-x8-ddr4-2400-b.json", 2400, 8, 8, "Micron",
                                            "MT40A1G8 (8Gb x8 rev B)",
                                            "Micron MTA18ASF2G72HZ datasheet Rev. F, Table 15",
        timings="DRAMsim3 configs/DDR4_8Gb_x8_2400.ini"),
    "micron-8gb-x4-ddr4-2400-b": PresetInfo("micron-8gb-x4-ddr4-2400-b.json", 2400, 8, 4, "Micron",
                                            "MT40A2G4 (8Gb x4)",
                                            "Micron 8Gb DDR4 datasheet x4 DDR4-2400 IDDs as gem5's DDR4_2400_16x4 quotes",
        timings="DRAMsim3 configs/DDR4_8Gb_x4_2400.ini"),
    "micron-8gb-x16-ddr4-2666-b": PresetInfo("micron-8gb-x16-ddr4-2666-b.json", 2666, 8, 16, "Micron",
                                             "MT40A512M16 (8Gb x16 rev B)",
                                             "Micron MTA4ATF51264AZ datasheet Rev. B, Table 13 (2666)",
        timings="JESD79-4 DDR4-2666V (19-19-19), 2 KB page"),
    "micron-4gb-x4-ddr4-2133": PresetInfo("micron-4gb-x4-ddr4-2133.json", 2133, 4, 4, "Micron", "MT40A1G4 (4Gb x4)",
                                          "Micron 4Gb DDR4 datasheet as DRAMsim3 DDR4_4Gb_x4_2133 quotes it",
        timings="DRAMsim3 configs/DDR4_4Gb_x4_2133.ini"),
    "micron-4gb-x4-ddr4-2400": PresetInfo("micron-4gb-x4-ddr4-2400.json", 2400, 4, 4, "Micron", "MT40A1G4 (4Gb x4)",
                                          "Micron 4Gb DDR4 datasheet as DRAMsim3 DDR4_4Gb_x4_2400 quotes it",
        timings="DRAMsim3 configs/DDR4_4Gb_x4_2400.ini"),
    "micron-8gb-x8-ddr4-2666": PresetInfo("micron-8gb-x8-ddr4-2666.json", 2666, 8, 8, "Micron", "MT40A1G8 (8Gb x8)",
                                          "Micron 8Gb DDR4 datasheet as DRAMsim3 DDR4_8Gb_x8_2666 quotes it",
        timings="DRAMsim3 configs/DDR4_8Gb_x8_2666.ini"),
    "micron-8gb-x8-ddr4-2933": PresetInfo("micron-8gb-x8-ddr4-2933.json", 2933, 8, 8, "Micron", "MT40A1G8 (8Gb x8)",
                                          "Micron 8Gb DDR4 datasheet as DRAMsim3 DDR4_8Gb_x8_2933 quotes it",
        timings="DRAMsim3 configs/DDR4_8Gb_x8_2933.ini"),
    "micron-8gb-x4-ddr4-2666": PresetInfo("micron-8gb-x4-ddr4-2666.json", 2666, 8, 4, "Micron", "MT40A2G4 (8Gb x4)",
                                          "Micron 8Gb DDR4 datasheet as DRAMsim3 DDR4_8Gb_x4_2666 quotes it",
        timings="DRAMsim3 configs/DDR4_8Gb_x4_2666.ini"),
    "micron-8gb-x4-ddr4-2933": PresetInfo("micron-8gb-x4-ddr4-2933.json", 2933, 8, 4, "Micron", "MT40A2G4 (8Gb x4)",
                                          "Micron 8Gb DDR4 datasheet as DRAMsim3 DDR4_8Gb_x4_2933 quotes it",
        timings="DRAMsim3 configs/DDR4_8Gb_x4_2933.ini"),
    "micron-8gb-x4-ddr4-3200": PresetInfo("micron-8gb-x4-ddr4-3200.json", 3200, 8, 4, "Micron", "MT40A2G4 (8Gb x4)",
                                          "Micron 8Gb DDR4 datasheet as DRAMsim3 DDR4_8Gb_x4_3200 quotes it",
        timings="DRAMsim3 configs/DDR4_8Gb_x4_3200.ini"),
    "micron-8gb-x8-ddr4-3200-g": PresetInfo("micron-8gb-x8-ddr4-3200-g.json", 3200, 8, 8, "Micron",
                                            "MT40A1G8 (8Gb x8 rev G)",
                                            "DRAMPower memspec MICRON_8Gb_DDR4-3200_8bit_G (8gb_ddr4_sdram.pdf)",
        timings="DRAMPower memspec MICRON_8Gb_DDR4-3200_8bit_G"),
}

#: Preset name -> file name in this directory.
PRESETS: dict[str, str] = {name: info.file for name, info in PRESET_INFO.items()}


def preset_path(name: str) -> Path:
    """Path of the JSON file of preset ``name`` (a key of :data:`PRESETS`)."""
    return Path(__file__).resolve().parent / PRESETS[name]
