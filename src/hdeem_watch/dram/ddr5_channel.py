"""DDR5 command statistics: a DIMM's two sub-channels run through the controller model.

A DDR5 DIMM has two independent 32-bit sub-channels; DRAMPower's (and DRAMSys') DDR5 memspec
describes one of them (``width × nbrOfDevices`` data bits, ``nbrOfRanks`` ranks of
``nbrOfBankGroups`` × banks). With BL16 one burst of a 32-bit sub-channel carries one 64-byte
line, and consecutive lines alternate between the sub-channels (the ``Ch`` field of the mapping).

:func:`subchannel_spec` gives the controller model (:mod:`hdeem_watch.dram.controller`) the
sub-channel as its vocabulary spells a channel: the organisation of the memarchitecturespec (8 bank
groups × 4 banks on x4/x8, 4 × 4 on x16: whatever the file says), two channels, and the DDR5
timings — tCCD_L/S from ``CCD_L_slr``/``CCD_S_slr``, write-to-write in a bank group from
``CCD_L_WR_slr``, tWTR_L/S, tRTP, tWR, tRCD, tRP, tRAS, RL/WL, and all-bank refresh every
``REFI1`` with ``RFC1_slr`` (``RefMode`` 1) or every ``REFI2`` with ``RFC2_slr`` (``RefMode`` 2).
tRRD_L/S and tFAW are carried but not enforced (as for DDR4: see docs/dram-stats.md); same-bank
refresh is not issued by the model (``refsb`` is 0; a REFsb trace goes through ``model energy``).

The statistics are :class:`~hdeem_watch.dram.stats.CommandStats` of one sub-channel, which
:func:`hdeem_watch.dram.energy_ddr5.core_energy_ddr5` turns into joules with the DDR5 memspec.

Example:
    >>> import json, pathlib
    >>> from hdeem_watch.dram.memspec_ddr5 import parse_memspec_ddr5
    >>> data = json.loads((pathlib.Path(__file__).parents[3] / "examples" / "ddr5_drampower_test.json").read_text())
    >>> arch = data["memspec"]["memarchitecturespec"]
    >>> arch.update(burstLength=16, nbrOfDevices=4, nbrOfBankGroups=8, nbrOfBanks=32)
    >>> data["memspec"]["memtimingspec"].update(REFI1=9360, REFI2=4680, CCD_S_slr=8, CCD_L_slr=12)
    >>> sub = subchannel_spec(parse_memspec_ddr5(data))
    >>> sub.nbr_of_channels, sub.nbr_of_bankgroups, sub.timings["REFI"], LINE_BYTES
    (2, 8, 9360, 64)
"""

from __future__ import annotations

from typing import Any

from hdeem_watch.dram.kernels import KernelModel, kernel_stats
from hdeem_watch.dram.memspec import MemSpec
from hdeem_watch.dram.memspec_ddr5 import MemSpecDDR5
from hdeem_watch.errors import InputError

#: Independent sub-channels per DDR5 DIMM (channel as the CPU's memory controller sees it).
SUBCHANNELS = 2
#: Bytes one burst of a sub-channel carries: a cache line.
LINE_BYTES = 64

#: controller timing <- DDR5 memtimingspec field (the refresh pair depends on RefMode).
_TIMINGS: dict[str, str] = {
    "RAS": "RAS", "RCD": "RCD", "RP": "RP", "RL": "RL", "WL": "WL", "RTP": "RTP", "WR": "WR",
    "CCD_S": "CCD_S_slr", "CCD_L": "CCD_L_slr", "CCD_L_WR": "CCD_L_WR_slr", "WTR_S": "WTR_S",
    "WTR_L": "WTR_L", "RTRS": "RTRS", "RRD_S": "RRD_S_slr", "RRD_L": "RRD_L_slr", "FAW": "FAW_slr",
}
#: Timings the controller cannot do without (a zero would make bursts overlap or refresh never end).
_POSITIVE = ("RCD", "RP", "RAS", "CCD_S_slr", "CCD_L_slr")


def refresh_interval(spec: MemSpecDDR5) -> int:
    """tREFI of the memspec's refresh mode in cycles: ``REFI2`` in mode 2, else ``REFI1``."""
    return int(spec.timings["REFI2" if spec.ref_mode == 2 else "REFI1"])


def controller_spec(spec: MemSpec | MemSpecDDR5) -> MemSpec:
    """The memspec of one channel as the controller model spells it: a DDR4 memspec as it is, a DDR5
    memspec's sub-channel (:func:`subchannel_spec`; a DDR5 node's channels are its sub-channels)."""
    return subchannel_spec(spec) if isinstance(spec, MemSpecDDR5) else spec


def subchannel_spec(spec: MemSpecDDR5) -> MemSpec:
    """One sub-channel of ``spec`` as the controller model's channel (two per DIMM).

    Raises:
        InputError: a burst that is not one 64-byte line (``width × nbrOfDevices × burstLength / 8``),
            a refresh interval of 0 for the mode, or a zero core timing (named).
    """
    bits = spec.width * spec.nbr_of_devices
    burst_bytes = (1 << (bits.bit_length() - 1)) * spec.burst_length // 8
    if burst_bytes != LINE_BYTES:
        raise InputError(
            f"memspec {spec.memory_id!r}: a burst carries {burst_bytes} bytes (width {spec.width} × "
            f"{spec.nbr_of_devices} devices × burstLength {spec.burst_length} / 8); the DDR5 controller "
            f"model needs one {LINE_BYTES}-byte line per burst of a 32-bit sub-channel (e.g. BL16, 4 × x8)")
    refi_key = "REFI2" if spec.ref_mode == 2 else "REFI1"
    for key in (*_POSITIVE, refi_key):
        if int(spec.timings.get(key, 0)) <= 0:
            raise InputError(f"memspec {spec.memory_id!r}: memtimingspec.{key} = {spec.timings.get(key, 0)}; "
                             f"the DDR5 controller model needs a positive value")
    timings: dict[str, int] = {ours: int(spec.timings[theirs]) for ours, theirs in _TIMINGS.items()}
    timings.update(AL=0, RFC1=spec.trfc, REFI=refresh_interval(spec))
    if timings["RTRS"] <= 0:
        timings["RTRS"] = 1
    return MemSpec(
        memory_id=f"{spec.memory_id} (sub-channel)", memory_type="DDR5", nbr_of_channels=SUBCHANNELS,
        nbr_of_devices=spec.nbr_of_devices, nbr_of_ranks=spec.nbr_of_ranks, nbr_of_banks=spec.nbr_of_banks,
        nbr_of_bankgroups=spec.nbr_of_bankgroups, nbr_of_rows=spec.nbr_of_rows,
        nbr_of_columns=spec.nbr_of_columns, burst_length=spec.burst_length, data_rate=spec.data_rate,
        width=spec.width, max_burst_length=spec.burst_length, ref_mode=1, tck_s=spec.tck_s, timings=timings,
        currents=dict(spec.currents), vdd=spec.vdd, vpp=spec.vpp, vddq=spec.vddq, fact_rho=spec.fact_rho)


def kernel_stats_ddr5(spec: MemSpecDDR5, kernel: str, elements: int, threads: int, *, channels: int = 1,
                      **options: Any) -> KernelModel:
    """:func:`~hdeem_watch.dram.kernels.kernel_stats` of one sub-channel of one of ``channels`` DIMMs.

    The kernel's lines are spread over ``2 × channels`` sub-channels; the statistics (reads, writes:
    one burst per line) are those of one of them. ``options``: ``kernel_stats``'s keyword arguments.
    """
    return kernel_stats(subchannel_spec(spec), kernel, elements, threads, channels=SUBCHANNELS * channels,
                        **options)
