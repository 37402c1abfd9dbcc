"""Built-in DDR4 memspecs (DRAMPower JSON files in this directory) and where each number comes from.

``ddr4-2133-x8-4gb`` (``ddr4-2133-x8-4gb.json``)
    A byte-for-byte copy of ``reference/drampower/memspecs/ddr4_2133_x8_2r_8dev.json``, the device
    the DRAMPower v6.2 reference outputs were computed with: DDR4-2133 (tCK 0.9375 ns, 15-15-15,
    RAS 36, RC 51, RFC1 278, REFI 8320 cycles), 4 Gb x8, 16 banks in 4 bank groups, 32768 rows x
    1024 columns, 2 ranks x 8 devices. Currents per device (the reference README): the mid-point of
    the Micron 4 Gb x8 rev-A DDR4-1866 and DDR4-2400 memspecs that DRAMPower 4.1 shipped (IDD0 58.5,
    IDD2N 36.0, IDD3N 41.75, IDD4R 171.0, IDD4W 151.875, IDD5B 118, IDD6N 20.25, IDD2P 17,
    IDD3P 22.5, IPP0 4.05, IPP6N 2.6 mA, other IPP 0); VDD 1.2, VPP 2.5, VDDQ 1.2 V. Interface
    impedances are DRAMPower's test placeholders (1 MOhm, 1 pJ), not a real board.

``samsung-m393a1g43db0-cpb`` (``samsung-m393a1g43db0-cpb.json``)
    Samsung M393A1G43DB0-CPB, 8 GB DDR4-2133P (15-15-15) registered ECC DIMM, 2 ranks x 9 x8 4 Gb
    dies (8 data + 1 ECC per rank), as on the Haswell-EP nodes (Taurus) of the seed paper.

    - Geometry (2 ranks, 9 devices per rank, x8, 16 banks in 4 groups, 32768 x 1024, BL8, DDR):
      the module's organisation (1G x 72, 2Rx8, 4 Gb dies) and the JEDEC DDR4 4 Gb x8 addressing.
    - Timings: identical to ``ddr4-2133-x8-4gb`` (DDR4-2133P: tCK 0.9375 ns, CL-RCD-RP 15-15-15,
      RAS 36 = 33 ns, RC 51, RFC1 278 = 260 ns for 4 Gb, REFI 8320 = 7.8 us), i.e. the JEDEC
      DDR4-2133P speed bin; no module-specific timing was used.
    - IDD0, IDD2N, IDD3N, IDD4R, IDD4W: the module datasheet figures quoted second-hand in
      DESIGN.md section 4 (per module: 1120, 1040, 1540, 1750, 1590 mA), converted to per device by
      dividing by the 18 dies of the module (2 ranks x 9): per device = module / 18, e.g. IDD0
      1120 / 18 = 62.2 mA. This assumes every die is in the measured state and attributes the
      register/PLL (RCD) current to the dies, so these figures are upper bounds on the dies' own
      currents; that is also what the seed paper calibrated against (its calibrated / datasheet
      ratios are 0.35-0.58).
    - IDD5B, IDD6N, IDD2P, IDD3P, every IPP, VDD/VPP/VDDQ and the interface section: no public
      per-device figure for this module was available to us, so the reference device's values
      (``ddr4-2133-x8-4gb``, above) are used unchanged.
"""

from __future__ import annotations

from pathlib import Path

#: Preset name -> file name in this directory.
PRESETS: dict[str, str] = {
    "ddr4-2133-x8-4gb": "ddr4-2133-x8-4gb.json",
    "samsung-m393a1g43db0-cpb": "samsung-m393a1g43db0-cpb.json",
}


def preset_path(name: str) -> Path:
    """Path of the JSON file of preset ``name`` (a key of :data:`PRESETS`)."""
    return Path(__file__).resolve().parent / PRESETS[name]
