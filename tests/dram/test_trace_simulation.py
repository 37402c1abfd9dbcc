"""simulate_trace: statistics straight from a trace file, parsed chunk by chunk in the pipeline."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hdeem_watch.dram import controller
from hdeem_watch.dram.controller import simulate
from hdeem_watch.dram.kernels import kernel_requests
from hdeem_watch.dram.memspec import preset
from hdeem_watch.dram.request_traces import format_requests, write_requests
from hdeem_watch.dram.trace_simulation import simulate_trace
from hdeem_watch.errors import InputError


@pytest.fixture
def small_chunks(monkeypatch: pytest.MonkeyPatch) -> None:
    """Chunks of 4096 requests: a short trace is many chunks (the worker process path)."""
    monkeypatch.setattr(controller, "CHUNK_REQUESTS", 1 << 12)


def _same(a, b) -> bool:  # type: ignore[no-untyped-def]
    return (a.stats == b.stats and a.cycles == b.cycles and a.requests == b.requests
            and (a.row_hits, a.row_misses, a.row_conflicts) == (b.row_hits, b.row_misses, b.row_conflicts))


@pytest.mark.slow
@pytest.mark.parametrize("fmt", ["ramulator", "ramulator2"])
@pytest.mark.parametrize("policy", ["open", "closed"])
def test_a_trace_file_gives_the_statistics_of_its_requests(tmp_path: Path, small_chunks: None, fmt: str,
                                                             policy: str) -> None:
    """Streaming a uniform trace through the pipeline gives exactly simulate() of its requests."""
    addresses, is_write = kernel_requests("triad", 8 * 12_000, threads=3)
    path = tmp_path / "t.trace"
    write_requests(path, addresses, is_write, fmt)
    result, cpu = simulate_trace(preset("ddr4-2133-x8-4gb"), path, fmt, policy=policy)
    assert cpu == 0
    assert _same(result, simulate(preset("ddr4-2133-x8-4gb"), addresses, is_write, policy=policy))


@pytest.mark.slow
def test_mixed_line_lengths_take_the_general_reader(tmp_path: Path, small_chunks: None) -> None:
    """A trace whose lines differ in length (even when the file size is a multiple of the first
    line's) gives the same statistics through the general reader."""
    addresses, is_write = kernel_requests("copy", 8 * 6000, threads=2)
    text = format_requests(addresses, is_write)
    first = text.index(b"\n") + 1
    # a short address line among the long ones, padded so the size stays a multiple of the first line
    odd = b"0x40 R\n"
    body = text[:first * 7000] + odd + text[first * 7000:]
    body += b"\n" * (-len(body) % first)
    path = tmp_path / "mixed.trace"
    path.write_bytes(body)
    result, _ = simulate_trace(preset("ddr4-2133-x8-4gb"), path, "ramulator")
    ref_addresses = np.insert(addresses, 7000, 0x40)
    ref_writes = np.insert(is_write, 7000, False)
    assert _same(result, simulate(preset("ddr4-2133-x8-4gb"), ref_addresses, ref_writes))


@pytest.mark.slow
def test_a_malformed_line_deep_in_a_uniform_trace_is_named(tmp_path: Path, small_chunks: None) -> None:
    """A bad line in a later chunk (parsed by the worker) is an InputError with its line number."""
    addresses, is_write = kernel_requests("read", 8 * 40_000)
    text = bytearray(format_requests(addresses, is_write))
    width = text.index(b"\n") + 1
    bad = 30_000  # 0-based line
    text[bad * width + width - 2] = ord("X")  # 'R' -> 'X'
    path = tmp_path / "bad.trace"
    path.write_bytes(bytes(text))
    with pytest.raises(InputError, match=rf"{path.name}:{bad + 1}:"):
        simulate_trace(preset("ddr4-2133-x8-4gb"), path, "ramulator")
