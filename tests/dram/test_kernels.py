"""Kernel request streams: identical to the Ramulator reference traces, traffic counts, threads."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hdeem_watch.dram.kernels import (
    ARRAY_BASES,
    KERNELS,
    access_pattern,
    kernel_requests,
    kernel_traffic,
    thread_line_order,
)
from hdeem_watch.dram.request_traces import format_requests, trace_sha256
from hdeem_watch.errors import InputError

REFERENCE = Path(__file__).resolve().parents[1] / "data" / "ramulator"


def _meta(name: str) -> dict:
    return json.loads((REFERENCE / "trace_meta" / name).read_text())


@pytest.mark.slow
@pytest.mark.parametrize(("meta_file", "fmt"), [("v1_wb0.json", "ramulator"), ("v2ls_wb0.json", "ramulator2")])
def test_streams_reproduce_reference_trace_hashes(meta_file: str, fmt: str) -> None:
    """The generated stream, written as trace text, has the sha256 of the reference trace of every kernel."""
    meta = _meta(meta_file)
    elements = meta["_params"]["doubles_per_array"]
    assert {int(v, 16) for v in meta["_params"]["bases"].values()} == set(ARRAY_BASES.values())
    digests: dict[tuple, str] = {}
    for kernel in KERNELS:
        addresses, is_write = kernel_requests(kernel, elements, threads=1)
        entry = meta[kernel]
        assert addresses.size == entry["requests"]
        assert int(is_write.sum()) == entry["writes"]
        key = access_pattern(kernel)  # identical patterns give identical text: hash once
        if key not in digests:
            digests[key] = trace_sha256(addresses, is_write, fmt)
        assert digests[key] == entry["sha256"], kernel


def test_traffic_counts_match_the_streams() -> None:
    """kernel_traffic is the pure count of the reads (write-allocate included) and writes of the stream."""
    for kernel in (*KERNELS, "addition"):
        for elements in (0, 1, 8, 9, 1000):
            traffic = kernel_traffic(kernel, elements)
            _, is_write = kernel_requests(kernel, elements, threads=3)
            assert traffic.lines_written == int(is_write.sum())
            assert traffic.lines_read == int((~is_write).sum())
    assert kernel_traffic("copy", 800) == kernel_traffic("scale", 800)
    assert kernel_traffic("add", 80).lines_read == 30  # a, b and the write-allocate of c
    assert kernel_traffic("triad", 80).lines_read == 20  # a is a source: no extra read-for-ownership


def test_threads_take_contiguous_chunks_interleaved_round_robin() -> None:
    """Thread t owns a contiguous chunk (static schedule) and the controller sees one iteration per thread in turn."""
    order = thread_line_order(10, 3)  # chunks 0-3, 4-6, 7-9
    assert order.tolist() == [0, 4, 7, 1, 5, 8, 2, 6, 9, 3]
    addresses, is_write = kernel_requests("copy", 10 * 8, threads=3)
    assert sorted(set(addresses.tolist())) == sorted(
        {ARRAY_BASES[a] + 64 * k for a in "ab" for k in range(10)})
    # per iteration: read a[k], read b[k] (write-allocate), write b[k]
    assert addresses[:3].tolist() == [ARRAY_BASES["a"], ARRAY_BASES["b"], ARRAY_BASES["b"]]
    assert addresses[3] == ARRAY_BASES["a"] + 4 * 64
    assert is_write.reshape(-1, 3).tolist() == [[False, False, True]] * 10


def test_alias_and_bad_arguments() -> None:
    """'addition' is the add kernel; unknown kernels, negative sizes and zero threads are InputErrors."""
    a1, w1 = kernel_requests("addition", 64, 2)
    a2, w2 = kernel_requests("add", 64, 2)
    assert np.array_equal(a1, a2) and np.array_equal(w1, w2)
    with pytest.raises(InputError, match="unknown"):
        kernel_requests("nope", 64)
    with pytest.raises(InputError, match="elements"):
        kernel_traffic("copy", -1)
    with pytest.raises(InputError, match="threads"):
        kernel_requests("copy", 64, 0)


def test_text_format_has_no_leading_zeros() -> None:
    """Trace text prints lowercase hex without leading zeros, R/W or LD/ST as the format says."""
    addresses = np.array([0, 0x1F, 0xABC0, 1 << 40], dtype=np.uint64)
    is_write = np.array([False, True, False, True])
    assert format_requests(addresses, is_write) == b"0x0 R\n0x1f W\n0xabc0 R\n0x10000000000 W\n"
    assert format_requests(addresses, is_write, "ramulator2") == (
        b"LD 0x0\nST 0x1f\nLD 0xabc0\nST 0x10000000000\n")
