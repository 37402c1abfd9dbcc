"""Address mapping: bit-slice schemes, round trips, XOR bank hashing, geometry errors."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from hdeem_watch.dram.mapping import SCHEMES, AddressMapping, Fields, Geometry
from hdeem_watch.errors import InputError

GEOMETRY = Geometry(channels=2, ranks=2, bankgroups=4, banks_per_group=4, rows=65536, columns=1024,
                    burst_length=8, transaction_bytes=64)


def _random_fields(rng: np.random.Generator, n: int, geometry: Geometry = GEOMETRY) -> Fields:
    bankgroup = rng.integers(0, geometry.bankgroups, n)
    bank = rng.integers(0, geometry.banks_per_group, n)
    return Fields(channel=rng.integers(0, geometry.channels, n), rank=rng.integers(0, geometry.ranks, n),
                  bankgroup=bankgroup, bank=bank, row=rng.integers(0, geometry.rows, n),
                  column=rng.integers(0, geometry.bursts_per_row, n),
                  flat_bank=bankgroup * geometry.banks_per_group + bank)


@pytest.mark.parametrize("scheme", SCHEMES)
@pytest.mark.parametrize("xor_bank", [False, True])
def test_encode_decode_round_trip(scheme: str, xor_bank: bool) -> None:
    """decode(encode(fields)) gives the fields back and encode(decode(a)) the line address, for every scheme."""
    mapping = AddressMapping(GEOMETRY, scheme, xor_bank=xor_bank)
    rng = np.random.default_rng(1)
    fields = _random_fields(rng, 10_000)
    back = mapping.decode(mapping.encode(fields))
    for name in ("channel", "rank", "bankgroup", "bank", "row", "column", "flat_bank"):
        assert np.array_equal(getattr(back, name), getattr(fields, name)), name
    addresses = rng.integers(0, 1 << mapping.address_bits, 10_000, dtype=np.uint64)
    assert np.array_equal(mapping.encode(mapping.decode(addresses)), addresses & ~np.uint64(63))
    # a bijection on line addresses: distinct lines map to distinct field tuples
    assert mapping.address_bits == 6 + 1 + 1 + 2 + 2 + 16 + 7


def test_ramulator_default_layout() -> None:
    """RoBaRaCoCh: from the LSB 6 offset, channel, 7 column, rank, 2 bank-group, 2 bank, then row bits."""
    geometry = Geometry(channels=1, ranks=2, bankgroups=4, banks_per_group=4, rows=65536, columns=1024,
                        burst_length=8, transaction_bytes=64)
    mapping = AddressMapping(geometry, "RoBaRaCoCh")
    lines = np.arange(0, 4096, dtype=np.uint64) * np.uint64(64)
    fields = mapping.decode(lines)
    assert fields.column[:128].tolist() == list(range(128))
    assert (fields.rank[:128] == 0).all() and (fields.rank[128:256] == 1).all()
    assert fields.bankgroup[256] == 1 and fields.bank[256] == 0  # bank-group bits below the bank bits
    assert fields.bank[1024] == 1 and fields.bankgroup[1024] == 0
    assert mapping.decode(np.array([1 << 30], dtype=np.uint64)).row[0] == 1 << 12
    assert mapping.decode(np.array([1 << 34], dtype=np.uint64)).row[0] == 0  # wraps like Ramulator


def test_channel_first_scheme_puts_channel_on_top() -> None:
    """ChRaBaRoCo: the channel is the most significant field and consecutive lines stay in one row."""
    mapping = AddressMapping(GEOMETRY, "ChRaBaRoCo")
    fields = mapping.decode(np.array([0, 64, 1 << (mapping.address_bits - 1)], dtype=np.uint64))
    assert fields.channel.tolist() == [0, 0, 1]
    assert fields.column.tolist() == [0, 1, 0]
    assert fields.row.tolist() == [0, 0, 0]


def test_xor_hashing_spreads_same_bank_arrays() -> None:
    """With XOR hashing, two arrays 1 GiB apart (same bank, different rows) land in different banks."""
    geometry = Geometry(channels=1, ranks=2, bankgroups=4, banks_per_group=4, rows=65536, columns=1024,
                        burst_length=8, transaction_bytes=64)
    base = np.array([1 << 30, 2 << 30], dtype=np.uint64)
    plain = AddressMapping(geometry, "RoBaRaCoCh").decode(base)
    hashed = AddressMapping(geometry, "RoBaRaCoCh", xor_bank=True).decode(base + np.uint64(1 << 21))
    assert plain.flat_bank[0] == plain.flat_bank[1]
    assert hashed.flat_bank[0] != hashed.flat_bank[1]


@pytest.mark.parametrize(("scheme", "message"), [
    ("RoBaRaCo", "missing field"), ("RoBaRaCoChCo", "twice"), ("RoBxRaCoCh", "unknown field"),
    ("robaracoch", "expected field tokens"),
])
def test_bad_schemes_are_input_errors(scheme: str, message: str) -> None:
    """A malformed scheme is an InputError that says what is wrong."""
    with pytest.raises(InputError, match=message):
        AddressMapping(GEOMETRY, scheme)


def test_geometry_that_does_not_fit() -> None:
    """A memspec with a count that is not a power of two cannot be bit-sliced: InputError naming the field."""
    spec = SimpleNamespace(nbr_of_channels=1, nbr_of_ranks=3, nbr_of_bankgroups=4, nbr_of_banks=16,
                           nbr_of_rows=65536, nbr_of_columns=1024, burst_length=8, width=8, nbr_of_devices=8)
    with pytest.raises(InputError, match="ranks = 3"):
        Geometry.from_spec(spec)
    spec.nbr_of_ranks = 2
    assert Geometry.from_spec(spec).transaction_bytes == 64
    big = Geometry(channels=1 << 20, ranks=2, bankgroups=4, banks_per_group=4, rows=1 << 30, columns=1024,
                   burst_length=8, transaction_bytes=64)
    with pytest.raises(InputError, match="address bits"):
        AddressMapping(big, "RoBaRaCoCh")
