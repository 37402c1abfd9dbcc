"""Physical address → channel, rank, bank group, bank, row, column: bit-slice mapping schemes.

A scheme names the address fields from the most to the least significant bit, e.g. ``RoBaRaCoCh``
(Ramulator's default): row, bank, rank, column, channel, above the transaction-offset bits. Field
tokens: ``Ro`` row, ``Ba`` bank, ``Bg`` bank group, ``Ra`` rank, ``Co`` column, ``Ch`` channel.
Without an explicit ``Bg`` the ``Ba`` field holds the bank-group bits below the bank bits, as in
Ramulator's DDR4 (so consecutive banks of the flat index alternate bank groups). Field widths come
from the memspec: ``log2`` of channels, ranks, bank groups, banks per group, rows, and of the
columns per burst (``nbrOfColumns / burstLength``); the offset is ``log2`` of the transaction size
(``width × devices × burstLength / 8`` bytes, 64 for a 64-bit BL8 channel; the ECC devices of
a 72-bit rank carry no address bits). Address bits above the
mapped ones are ignored (the address wraps), as in Ramulator.

``xor_bank=True`` XORs the flat bank index with the XOR-fold of the row bits (permutation-based
interleaving), spreading row conflicts of arrays that differ only in row bits over banks.

Example:
    >>> geometry = Geometry(channels=1, ranks=2, bankgroups=4, banks_per_group=4, rows=65536,
    ...                     columns=1024, burst_length=8, transaction_bytes=64)
    >>> mapping = AddressMapping(geometry, "RoBaRaCoCh")
    >>> fields = mapping.decode(np.array([0x40000000 + 128 * 64], dtype=np.uint64))
    >>> int(fields.rank[0]), int(fields.row[0]), int(fields.column[0])
    (1, 4096, 0)
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from hdeem_watch.dram.memspec import MemSpec
from hdeem_watch.errors import InputError

#: Named schemes (any other permutation of the tokens is accepted too).
SCHEMES = ("RoBaRaCoCh", "ChRaBaRoCo", "RoRaBaChCo", "RoCoBaRaCh", "RoRaBgBaCoCh")
_TOKENS = ("Ch", "Ra", "Bg", "Ba", "Ro", "Co")


@dataclass(frozen=True)
class Geometry:
    """Organisation of one memory system as the mapping sees it (all counts powers of two).

    Attributes:
        channels: channels.
        ranks: ranks per channel.
        bankgroups: bank groups per rank.
        banks_per_group: banks per bank group.
        rows: rows per bank.
        columns: device columns per row.
        burst_length: columns per burst (one request = one burst).
        transaction_bytes: bytes per request.
    """

    channels: int
    ranks: int
    bankgroups: int
    banks_per_group: int
    rows: int
    columns: int
    burst_length: int
    transaction_bytes: int

    @property
    def banks(self) -> int:
        """Banks per rank."""
        return self.bankgroups * self.banks_per_group

    @property
    def bursts_per_row(self) -> int:
        """Requests (bursts) per row."""
        return self.columns // self.burst_length

    @classmethod
    def from_spec(cls, spec: MemSpec, channels: int | None = None) -> Geometry:
        """The geometry of a memspec (``channels`` overrides ``nbr_of_channels``).

        Raises:
            InputError: if a count is not a positive power of two.
        """
        bankgroups = int(getattr(spec, "nbr_of_bankgroups", 1) or 1)
        banks = int(spec.nbr_of_banks)
        # an ECC rank (e.g. 9 x8 devices, 72 bits) carries 64 data bits: round down to a power of two
        bus_bits = int(spec.width) * int(spec.nbr_of_devices)
        bus_bits = 1 << (bus_bits.bit_length() - 1) if bus_bits > 0 else 0
        transaction = bus_bits * int(spec.burst_length) // 8
        geometry = cls(
            channels=int(channels if channels is not None else spec.nbr_of_channels),
            ranks=int(spec.nbr_of_ranks),
            bankgroups=bankgroups,
            banks_per_group=banks // bankgroups if banks % bankgroups == 0 else -1,
            rows=int(spec.nbr_of_rows),
            columns=int(spec.nbr_of_columns),
            burst_length=int(spec.burst_length),
            transaction_bytes=transaction,
        )
        for name in ("channels", "ranks", "bankgroups", "banks_per_group", "rows", "columns",
                     "burst_length", "transaction_bytes"):
            _log2(getattr(geometry, name), name)
        if geometry.columns < geometry.burst_length:
            raise InputError(f"memspec: {geometry.columns} columns per row < burst length {geometry.burst_length}")
        return geometry


def _log2(value: int, name: str) -> int:
    if value < 1 or value & (value - 1):
        raise InputError(f"memspec: {name} = {value} is not a power of two; a bit-slice mapping needs one")
    return value.bit_length() - 1


@dataclass(frozen=True)
class Fields:
    """Decoded request addresses (arrays of equal length).

    Attributes:
        channel, rank, bankgroup, bank, row, column: the fields; ``bank`` is the bank within its
            group, ``column`` the burst index within the row (device column = column × BL).
        flat_bank: bank index within the rank, ``bankgroup × banks_per_group + bank`` (DRAMPower).
    """

    channel: np.ndarray
    rank: np.ndarray
    bankgroup: np.ndarray
    bank: np.ndarray
    row: np.ndarray
    column: np.ndarray
    flat_bank: np.ndarray


class AddressMapping:
    """A bit-slice mapping scheme over a :class:`Geometry`.

    Args:
        geometry: the organisation.
        scheme: field tokens from MSB to LSB, e.g. ``"RoBaRaCoCh"``.
        xor_bank: XOR the flat bank index with the XOR-fold of the row.

    Raises:
        InputError: for an unknown token, a repeated or missing field, or a geometry that does not
            fit (not powers of two, more than 64 address bits).
    """

    def __init__(self, geometry: Geometry, scheme: str = "RoBaRaCoCh", *, xor_bank: bool = False) -> None:
        self.geometry = geometry
        self.scheme = scheme
        self.xor_bank = xor_bank
        tokens = re.findall(r"[A-Z][a-z]", scheme)
        if "".join(tokens) != scheme or not tokens:
            raise InputError(f"mapping {scheme!r}: expected field tokens {'/'.join(_TOKENS)} from MSB to LSB, e.g. RoBaRaCoCh")
        unknown = [t for t in tokens if t not in _TOKENS]
        if unknown:
            raise InputError(f"mapping {scheme!r}: unknown field {unknown[0]!r}; expected tokens {', '.join(_TOKENS)}")
        if len(set(tokens)) != len(tokens):
            raise InputError(f"mapping {scheme!r}: a field appears twice")
        missing = {"Ch", "Ra", "Ba", "Ro", "Co"} - set(tokens)
        if missing:
            raise InputError(f"mapping {scheme!r}: missing field(s) {', '.join(sorted(missing))}")
        widths = {
            "Ch": _log2(geometry.channels, "channels"), "Ra": _log2(geometry.ranks, "ranks"),
            "Bg": _log2(geometry.bankgroups, "bankgroups"), "Ba": _log2(geometry.banks_per_group, "banks_per_group"),
            "Ro": _log2(geometry.rows, "rows"), "Co": _log2(geometry.bursts_per_row, "columns per burst"),
        }
        self.offset_bits = _log2(geometry.transaction_bytes, "transaction_bytes")
        # LSB first: (token, shift, width); "Ba" without "Bg" holds the bank-group bits below.
        slices: list[tuple[str, int, int]] = []
        shift = self.offset_bits
        for token in reversed(tokens):
            if token == "Ba" and "Bg" not in tokens:
                slices.append(("Bg", shift, widths["Bg"]))
                shift += widths["Bg"]
            slices.append((token, shift, widths[token]))
            shift += widths[token]
        if shift > 64:
            raise InputError(f"mapping {scheme!r}: needs {shift} address bits; at most 64 fit")
        self.address_bits = shift
        self._slices = tuple(slices)

    def __repr__(self) -> str:
        return f"AddressMapping({self.scheme!r}, xor_bank={self.xor_bank}, bits={self.address_bits})"

    def _fold(self, row: np.ndarray) -> np.ndarray:
        """XOR of the row's bank-index-wide chunks (the bank hash)."""
        bits = self.geometry.banks.bit_length() - 1
        folded = np.zeros_like(row)
        if bits == 0:
            return folded
        rest = row.copy()
        while rest.any():
            folded ^= rest & (self.geometry.banks - 1)
            rest >>= bits
        return folded

    def decode(self, addresses: np.ndarray) -> Fields:
        """Split physical byte addresses into their fields (vectorised)."""
        # above the offset, every field fits a signed 64-bit integer: shift once, then slice
        line = (np.asarray(addresses, dtype=np.uint64) >> np.uint64(self.offset_bits)).view(np.int64)
        values: dict[str, np.ndarray] = {}
        for token, shift, width in self._slices:
            field = line >> (shift - self.offset_bits) if shift > self.offset_bits else line
            values[token] = field & ((1 << width) - 1)
        geometry = self.geometry
        flat = values["Bg"] * geometry.banks_per_group + values["Ba"]
        bankgroup, bank = values["Bg"], values["Ba"]
        if self.xor_bank:
            flat = flat ^ self._fold(values["Ro"])
            bankgroup, bank = flat // geometry.banks_per_group, flat % geometry.banks_per_group
        return Fields(channel=values["Ch"], rank=values["Ra"], bankgroup=bankgroup, bank=bank, row=values["Ro"],
                      column=values["Co"], flat_bank=flat)

    def decode_packed(self, addresses: np.ndarray, *, column: bool = True
                      ) -> tuple[np.ndarray | None, np.ndarray, np.ndarray, np.ndarray | None]:
        """The fields the controller needs, in as few passes as possible.

        Returns:
            ``(channel, bank, row, column)``: ``bank`` is the global bank index
            ``rank × banks + flat_bank``; ``channel`` is ``None`` for one channel, ``column``
            ``None`` unless asked for. Narrow integer types (``int32`` where the mapped bits fit).
        """
        geometry = self.geometry
        if self.xor_bank:
            fields = self.decode(addresses)
            return (fields.channel if geometry.channels > 1 else None,
                    fields.rank * geometry.banks + fields.flat_bank, fields.row,
                    fields.column if column else None)
        addresses = np.asarray(addresses, dtype=np.uint64)
        line = addresses >> np.uint64(self.offset_bits)
        if self.address_bits - self.offset_bits <= 31:
            line = line.astype(np.int32)  # the bits above are ignored anyway
        else:
            line = line.view(np.int64)
        # global bank: rank, bank group, bank (each a slice) packed as rank × banks + bg × per_group + ba
        place = {"Ra": (geometry.bankgroups * geometry.banks_per_group).bit_length() - 1,
                 "Bg": geometry.banks_per_group.bit_length() - 1, "Ba": 0}
        values: dict[str, np.ndarray | None] = {"Ch": None, "Co": None}
        gbank: np.ndarray | None = None
        for token, shift, width in self._slices:
            if width == 0 or (token == "Ch" and geometry.channels == 1) or (token == "Co" and not column):
                continue
            rel = shift - self.offset_bits
            if token in place:
                if place[token] >= rel:  # mask in place, then move left
                    part = line & ((1 << width) - 1) << rel
                    if place[token] > rel:
                        part <<= place[token] - rel
                else:
                    part = line >> (rel - place[token])
                    part &= ((1 << width) - 1) << place[token]
                if gbank is None:
                    gbank = part
                else:
                    gbank |= part
                continue
            field = line >> rel if rel else line.copy()
            field &= (1 << width) - 1
            values[token] = field
        if gbank is None:
            gbank = np.zeros(line.size, dtype=line.dtype)
        row = values.get("Ro")
        assert row is not None
        return values["Ch"], gbank, row, values["Co"]

    def encode(self, fields: Fields) -> np.ndarray:
        """The lowest physical address of each request (offset 0): the inverse of :meth:`decode`."""
        geometry = self.geometry
        flat = np.asarray(fields.bankgroup, dtype=np.int64) * geometry.banks_per_group + np.asarray(fields.bank)
        if self.xor_bank:
            flat = flat ^ self._fold(np.asarray(fields.row, dtype=np.int64))
        values = {
            "Ch": fields.channel, "Ra": fields.rank, "Bg": flat // geometry.banks_per_group,
            "Ba": flat % geometry.banks_per_group, "Ro": fields.row, "Co": fields.column,
        }
        address = np.zeros(np.shape(fields.row), dtype=np.uint64)
        for token, shift, width in self._slices:
            value = np.asarray(values[token]).astype(np.uint64) & np.uint64((1 << width) - 1)
            address |= value << np.uint64(shift)
        return address
