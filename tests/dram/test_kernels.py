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


# -- hold-out kernels (issue #32): workloads the calibration schedule never runs ----------------------


def test_holdout_kernels_move_the_lines_they_say() -> None:
    """Strides read every 2nd/4th line, the random kernels one random line of the array per iteration,
    mix31 three lines read and the first written back."""
    from hdeem_watch.dram.kernels import HOLDOUT_KERNELS, kernel_requests, kernel_traffic

    lines = (1 << 20) // 8
    assert kernel_traffic("stride2", 1 << 20).lines_read == lines // 2
    assert kernel_traffic("stride4", 1 << 20).lines_read == lines // 4
    assert kernel_traffic("gups", 1 << 20) == kernel_traffic("chase", 1 << 20) == kernel_traffic("read", 1 << 20)
    assert kernel_traffic("mix31", 1 << 20) == kernel_traffic("add", 1 << 20)  # 3 reads : 1 write
    addresses, is_write = kernel_requests("stride4", 1 << 12, threads=1)
    assert (np.diff(addresses.astype(np.int64)) == 4 * 64).all() and not is_write.any()
    addresses, _ = kernel_requests("gups", 1 << 16, threads=2)
    offsets = (addresses - (1 << 30)) // 64
    assert offsets.max() < (1 << 16) // 8 and len(np.unique(offsets)) > 0.5 * offsets.size  # random, within a
    assert not (np.diff(offsets.astype(np.int64)) == 1).mean() > 0.01
    addresses, is_write = kernel_requests("mix31", 64, threads=1)
    assert is_write.reshape(-1, 4).tolist()[0] == [False, False, False, True]
    assert set(HOLDOUT_KERNELS) == {"gups", "chase", "stride2", "stride4", "mix31"}


def test_the_model_gives_random_reads_an_activation_per_request() -> None:
    """Random 64-byte reads over 128 MiB miss the row buffer almost always; a 4-line stride reads a
    row's lines at a quarter of the stream's hits."""
    from hdeem_watch.dram.kernels import kernel_stats
    from hdeem_watch.dram.memspec import preset

    spec = preset("samsung-m393a1g43db0-cpb")
    act_per = {}
    for kernel in ("read", "stride4", "gups", "chase"):
        stats = kernel_stats(spec, kernel, 1 << 24, 4, channels=4, xor_bank=True).stats
        act_per[kernel] = stats.total("act") / (stats.total("rd") + stats.total("wr"))
    assert act_per["gups"] > 0.9 and act_per["chase"] > 0.9
    assert act_per["read"] < act_per["stride4"] < act_per["gups"]
