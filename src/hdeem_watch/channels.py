"""The channel vocabulary every layer shares: HDEEM's sensor names, the DIMM pairs, their sockets.

A bottom module (it imports nothing of the package), so the sources, the calibrator's printout
reader, the daemon and the TUI name channels the same way without importing each other.

Example:
    >>> DRAM_SOCKET["DDR_EF"]
    1
    >>> normalise_channel_name("Ddr Ab")
    'DDR_AB'
"""

from __future__ import annotations

import re

#: The HDEEM channels of a Haswell node, in HDEEM's own order.
CHANNELS = ("BLADE", "CPU0", "CPU1", "DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH")
#: The DIMM-pair channels (each covers two DIMMs, one per memory channel).
DRAM_CHANNELS = ("DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH")
#: Which socket each DIMM pair hangs off (DDR_AB, DDR_CD on socket 0; DDR_EF, DDR_GH on socket 1).
DRAM_SOCKET = {"DDR_AB": 0, "DDR_CD": 0, "DDR_EF": 1, "DDR_GH": 1}
#: RAPL reports DRAM per socket, not per pair: ``DRAM<n>`` covers these HDEEM channels.
RAPL_DRAM_COVERS = {"DRAM0": ("DDR_AB", "DDR_CD"), "DRAM1": ("DDR_EF", "DDR_GH")}


_SEP = re.compile(r"[\s_\-]+")


def normalise_channel_name(name: str) -> str:
    """Map a sensor name as a library or printout spells it onto :data:`CHANNELS`.

    Case, spaces, ``-`` and ``_`` vary between firmware versions ("ddr ab", "Ddr_Ab", "DDRAB");
    unknown names are returned upper-cased with separators replaced by ``_``.

    >>> normalise_channel_name(" ddr ab ")
    'DDR_AB'
    >>> normalise_channel_name("Blade")
    'BLADE'
    """
    squashed = _SEP.sub("", name).upper()
    for known in CHANNELS:
        if known.replace("_", "") == squashed:
            return known
    return _SEP.sub("_", name.strip()).upper()


def channel_letter(index: int) -> str:
    """The letter HDEEM gives a memory channel (node-wide index: A, B, ...; ``CH<n>`` beyond Z).

    >>> channel_letter(2), channel_letter(27)
    ('C', 'CH27')
    """
    return chr(ord("A") + index) if index < 26 else f"CH{index}"


def dimm_pair_channel(socket: int, channel: int, channels_per_socket: int) -> str:
    """The HDEEM sensor of a memory channel: consecutive channels of a socket in pairs (``DDR_AB``
    for channels 0 and 1 of socket 0), the last one alone when a socket has an odd number.

    >>> dimm_pair_channel(1, 3, 4), dimm_pair_channel(0, 2, 3)
    ('DDR_GH', 'DDR_C')
    """
    first = socket * channels_per_socket + (channel // 2) * 2
    second = min(first + 1, socket * channels_per_socket + channels_per_socket - 1)
    return "DDR_" + "".join(channel_letter(i) for i in sorted({first, second}))
