"""UniformParser (dram/uniform_parser.py): same-length Ramulator lines into addresses and flags."""

from __future__ import annotations

import numpy as np
import pytest

from hdeem_watch.dram.uniform_parser import UniformParser


def _lines(fmt: str, digits: int, count: int, seed: int, upper: bool = False) -> tuple[bytes, list[int], list[bool]]:
    rng = np.random.default_rng(seed)
    values = [int(v) for v in rng.integers(0, 1 << min(4 * digits, 63), count, dtype=np.uint64)]
    writes = [bool(w) for w in rng.random(count) < 0.4]
    out = []
    for value, write in zip(values, writes):
        text = f"{value:0{digits}x}"
        text = text.upper() if upper else text
        out.append(f"0x{text} {'W' if write else 'R'}\n" if fmt == "ramulator" else f"{'ST' if write else 'LD'} 0x{text}\n")
    return "".join(out).encode(), values, writes


def _parse(parser: UniformParser, data: bytes, length: int) -> tuple[bool, np.ndarray, np.ndarray]:
    rows = np.frombuffer(data, dtype=np.uint8).reshape(-1, length + 1)
    addresses = np.empty(rows.shape[0], dtype=np.uint64)
    writes = np.empty(rows.shape[0], dtype=bool)
    return parser.parse(rows, addresses, writes), addresses, writes


@pytest.mark.parametrize("fmt", ["ramulator", "ramulator2"])
@pytest.mark.parametrize("digits", [1, 3, 7, 8, 9, 14, 16])
@pytest.mark.parametrize("upper", [False, True])
def test_well_formed_lines_give_their_values(fmt: str, digits: int, upper: bool) -> None:
    """Every digit count (1-16, word and byte paths), both cases and both formats parse exactly,
    and a parser is reused across blocks."""
    parser = UniformParser(digits + 4 if fmt == "ramulator" else digits + 5, fmt, block=512)
    for seed in (1, 2):
        data, values, writes = _lines(fmt, digits, 300, seed, upper)
        ok, addresses, flags = _parse(parser, data, parser.length)
        assert ok
        assert addresses.tolist() == values and flags.tolist() == writes


@pytest.mark.parametrize("fmt", ["ramulator", "ramulator2"])
@pytest.mark.parametrize("digits", [2, 8, 16])
def test_any_corrupted_byte_is_rejected(fmt: str, digits: int) -> None:
    """Changing any one byte of one line to a character that breaks the form makes the block fail."""
    length = digits + 4 if fmt == "ramulator" else digits + 5
    parser = UniformParser(length, fmt, block=64)
    data, _, _ = _lines(fmt, digits, 40, 3)
    line = 17
    for column in range(length + 1):
        for bad in (b"g", b"G", b"/", b":", b"@", b"`", b"\x00", b"\xff", b"Z"):
            corrupted = bytearray(data)
            original = corrupted[line * (length + 1) + column]
            corrupted[line * (length + 1) + column] = bad[0]
            ok, _, _ = _parse(parser, bytes(corrupted), length)
            assert not ok, (column, bad, chr(original))
        # good again after a bad block (work arrays reused)
        assert _parse(parser, data, length)[0]


def test_unusable_lengths_and_oversized_blocks_are_not_parsed() -> None:
    """Lines too short for the format, more than 16 digits, or a block above the parser's size fail."""
    assert not UniformParser(4, "ramulator").usable  # '0x R' has no digit
    assert not UniformParser(21, "ramulator").usable  # 17 digits
    parser = UniformParser(12, "ramulator", block=4)
    data, _, _ = _lines("ramulator", 8, 5, 4)
    assert not _parse(parser, data, 12)[0]
    assert parser.parse(np.zeros((0, 13), dtype=np.uint8), np.empty(0, dtype=np.uint64), np.empty(0, dtype=bool))
