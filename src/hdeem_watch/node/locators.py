"""Which socket, channel and slot a DIMM sits in, read from the names boards and kernels give it.

Sources, in order of trust:

- EDAC labels the Intel drivers set by default: ``CPU_SrcID#0_MC#1_Chan#2_DIMM#0`` (skx/i10nm) or
  ``CPU_SrcID#0_Ha#0_Chan#3_DIMM#0`` (sb_edac): socket, memory controller, channel, slot.
- dmidecode ``Bank Locator`` of AMI-BIOS server boards: ``P0_Node0_Channel2_Dimm0`` or
  ``P0 CHANNEL A``. What ``NodeN`` means differs by board generation (Supermicro Haswell-EP boards
  repeat the socket, ``P1_Node1_Channel0_Dimm0``; Skylake-SP boards number the memory controller,
  ``P0_Node1_Channel2_Dimm0`` = socket 0, IMC 1, channel 2), so it is kept as ``node`` here and
  :mod:`.bank_nodes` decides per node which it is.
- dmidecode ``Locator`` names: ``CPU1_DIMM_A2``, ``P2-DIMMC1``, ``PROC 1 DIMM 3``, ``DIMM_P0_A1``
  (socket and channel letter), or a bare ``DIMM_A1`` / ``A1`` (channel letter only).

Channel letters are turned into per-socket channel numbers later (they restart per socket on some
boards and run on across sockets on others).

Example:
    >>> parse_location("CPU_SrcID#1_MC#0_Chan#2_DIMM#0", None)
    SlotGuess(socket=1, controller=0, channel=2, letter=None, slot=0, how='EDAC label', node=None)
    >>> parse_location("P2-DIMMC1", "P1_Node1_Channel2_Dimm0").socket
    1
    >>> parse_location("CPU1_DIMM_B2", "NODE 1")
    SlotGuess(socket=0, controller=None, channel=None, letter='B', slot=1, how='locator CPU<n>_DIMM_<letter><n>', node=None)
"""

from __future__ import annotations

import re
from dataclasses import dataclass


@dataclass(frozen=True)
class SlotGuess:
    """Where a DIMM sits, as far as a name tells (``None``: the name does not say).

    Attributes:
        socket: socket number (0-based).
        controller: memory controller (or home agent) within the socket.
        channel: channel number within the controller (or the socket, when ``controller`` is None).
        letter: channel letter of a board name (``"A"``), when that is all the name gives.
        slot: DIMM slot within the channel (0-based).
        how: which naming rule matched.
        node: ``NodeN`` of a ``P<n>_Node<n>_Channel<n>_Dimm<n>`` bank locator (socket or memory
            controller, decided for the whole node by :func:`.bank_nodes.bank_node_rule`).
    """

    socket: int | None
    controller: int | None
    channel: int | None
    letter: str | None
    slot: int | None
    how: str
    node: int | None = None


_EDAC = re.compile(r"CPU_SrcID#(\d+)_(?:MC|Ha)#(\d+)_Chan#(\d+)_DIMM#(\d+)", re.I)
_BANK_NODE = re.compile(r"P(\d+)_Node(\d+)_Channel(\d+)_Dimm(\d+)", re.I)
_BANK_CHANNEL = re.compile(r"P(\d+)\s+CHANNEL\s+([A-Z])\b", re.I)
_LOCATOR_RULES: tuple[tuple[re.Pattern[str], str, int], ...] = (
    (re.compile(r"(?:CPU|PROC|P)\s*(\d+)[\s_-]*DIMM[\s_-]*([A-Z])(\d+)", re.I), "locator CPU<n>_DIMM_<letter><n>", 1),
    (re.compile(r"DIMM[\s_-]*P(\d+)[\s_-]*([A-Z])(\d+)", re.I), "locator DIMM_P<n>_<letter><n>", 0),
)
_LETTER_ONLY = re.compile(r"(?:DIMM[\s_-]*)?([A-Z])(\d+)", re.I)


def locator_letter(locator: str) -> str | None:
    """The channel letter of a board slot name (``P2-DIMMF1`` → ``F``), ``None`` when it has none."""
    for pattern, _how, _base in _LOCATOR_RULES:
        if m := pattern.search(locator):
            return m.group(2).upper()
    return None


def parse_location(locator: str, bank_locator: str | None) -> SlotGuess:
    """Socket, channel and slot from a DIMM's names (an EDAC label or dmidecode's locators).

    Socket numbers that boards count from 1 (``CPU1``, ``P1-``, ``PROC 1``) are returned 0-based;
    slot numbers likewise (``A1`` is slot 0).
    """
    for text in (locator, bank_locator or ""):
        if m := _EDAC.search(text):
            return SlotGuess(int(m.group(1)), int(m.group(2)), int(m.group(3)), None, int(m.group(4)), "EDAC label")
    bank = bank_locator or ""
    if m := _BANK_NODE.search(bank):
        return SlotGuess(int(m.group(1)), None, int(m.group(3)), locator_letter(locator), int(m.group(4)),
                         "bank locator P<n>_Node<n>_Channel<n>_Dimm<n>", node=int(m.group(2)))
    if m := _BANK_CHANNEL.search(bank):
        slot = re.search(r"(\d+)\s*$", locator)
        return SlotGuess(int(m.group(1)), None, None, m.group(2).upper(), None if slot is None else 0,
                         "bank locator P<n> CHANNEL <letter>")
    for pattern, how, base in _LOCATOR_RULES:
        if m := pattern.search(locator):
            return SlotGuess(int(m.group(1)) - base, None, None, m.group(2).upper(), max(0, int(m.group(3)) - 1), how)
    if m := _LETTER_ONLY.fullmatch(locator.strip()):
        return SlotGuess(None, None, None, m.group(1).upper(), max(0, int(m.group(2)) - 1), "locator <letter><n>")
    return SlotGuess(None, None, None, None, None, f"locator {locator!r} not understood")
