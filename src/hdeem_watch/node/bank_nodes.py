"""What ``NodeN`` in ``P<s>_Node<n>_Channel<c>_Dimm<d>`` bank locators means on this node.

The same BIOS vendor prints two different things there (public ``dmidecode`` captures):

- Supermicro Haswell-EP boards (X10DRL-i, 2 × Xeon E5 v3): ``P1-DIMME1`` is
  ``P1_Node1_Channel0_Dimm0`` — ``NodeN`` repeats the socket, ``ChannelN`` (0-3) is the channel;
- Supermicro Skylake-SP boards (X11DDW-L, 2 × Xeon Gold 6148): ``P1-DIMMA1 … P1-DIMMF1`` are
  ``P0_Node0_Channel0_Dimm0 … P0_Node1_Channel2_Dimm0`` — ``NodeN`` is the memory controller inside
  the socket (2 IMCs × 3 channels = 6 channels per socket), ``ChannelN`` (0-2) the channel of that
  controller.

The decision, for the whole node: ``NodeN`` taking several values within one socket makes it the
memory controller; otherwise it is the socket. Two further facts are checked against the decision
and named in the rule: the slot letters of the ``Locator`` names (``A``–``F`` = 6 channels per
socket) and the channels per socket of the CPU's memory controller (:mod:`.cpu_model`).

Example:
    >>> from hdeem_watch.node.locators import parse_location
    >>> guesses = [parse_location(f"P1-DIMM{x}1", f"P0_Node{i // 3}_Channel{i % 3}_Dimm0")
    ...            for i, x in enumerate("ABCDEF")]
    >>> rule = bank_node_rule(guesses, None)
    >>> sorted({(rule.place(g).controller, g.channel) for g in guesses})[:4], rule.text.split(":")[0]
    ([(0, 0), (0, 1), (0, 2), (1, 0)], 'bank locator NodeN is the memory controller')
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

from hdeem_watch.node.cpu_model import MemoryController
from hdeem_watch.node.locators import SlotGuess


def _per_socket(guesses: Sequence[SlotGuess], key: str) -> dict[int, set[Any]]:
    out: dict[int, set[Any]] = defaultdict(set)
    for g in guesses:
        value = getattr(g, key)
        if g.socket is not None and value is not None:
            out[g.socket].add(value)
    return out


def _evidence(channels: int, letters: dict[int, set[Any]], controller: MemoryController | None) -> str:
    """The slot letters' and the CPU's word on ``channels`` per socket (agree / disagree)."""
    parts: list[str] = []
    if letters:
        counts = sorted({len(v) for v in letters.values()})
        verdict = "agree" if counts == [channels] else "disagree"
        parts.append(f"slot letters: {'/'.join(map(str, counts))} per socket {verdict}")
    if controller is not None:
        verdict = "agrees" if controller.channels_per_socket == channels else "disagrees"
        parts.append(f"{controller.generation}: {controller.channels_per_socket} channels per socket {verdict}")
    return "; ".join(parts)


@dataclass(frozen=True)
class BankNodeRule:
    """What ``NodeN`` is on this node, and why (the rule and its corroboration, one line)."""

    node_is_controller: bool
    text: str

    def place(self, guess: SlotGuess) -> SlotGuess:
        """``guess`` with its ``NodeN`` as the memory controller when that is what it is."""
        if self.node_is_controller and guess.node is not None:
            return replace(guess, controller=guess.node)
        return guess


def bank_node_rule(guesses: Sequence[SlotGuess], controller: MemoryController | None) -> BankNodeRule | None:
    """Decide what ``NodeN`` is from every slot's guess (``None``: no ``P<n>_Node<n>_…`` bank locator)."""
    banked = [g for g in guesses if g.node is not None and g.socket is not None]
    if not banked:
        return None
    nodes = _per_socket(banked, "node")
    letters = _per_socket(banked, "letter")
    varying = sorted(s for s, values in nodes.items() if len(values) > 1)
    if varying:
        channels = max(len({(g.node, g.channel) for g in banked if g.socket == s}) for s in nodes)
        head = (f"bank locator NodeN is the memory controller: it varies within socket P{varying[0]} "
                f"({', '.join(map(str, sorted(nodes[varying[0]])))}), so a channel is (NodeN, ChannelN)")
    else:
        channels = max(len({g.channel for g in banked if g.socket == s}) for s in nodes)
        head = "bank locator NodeN repeats the socket (one value per socket), so a channel is ChannelN"
    evidence = _evidence(channels, letters, controller)
    text = f"{head}; {channels} channels per socket" + (f" ({evidence})" if evidence else "")
    return BankNodeRule(bool(varying), text)
