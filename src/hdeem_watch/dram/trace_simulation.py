"""Command statistics straight from a request-trace file: parsing is part of the chunk pipeline.

A Ramulator trace whose lines all have one length (what the writers and the kernel streams
produce) is memory-mapped and parsed chunk by chunk in the preparing stage of
:func:`hdeem_watch.dram.controller.simulate_requests` (the worker process, while the chunk before
is timed), so reading costs no wall time of its own. Any other trace (mixed line lengths, CPU
traces through the cache filter) is read whole by
:func:`hdeem_watch.dram.request_traces.read_request_trace` first. A malformed line raises the
same ``InputError`` (file and line number) either way (a block that does not parse sends the
whole file to the general reader).

Example:
    >>> import tempfile, numpy as np
    >>> from pathlib import Path
    >>> from hdeem_watch.dram.memspec import preset
    >>> from hdeem_watch.dram.kernels import kernel_requests
    >>> from hdeem_watch.dram.request_traces import write_requests
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     path = Path(tmp) / "read.trace"
    ...     _ = write_requests(path, *kernel_requests("read", 8 * 4096))
    ...     result, cpu_accesses = simulate_trace(preset("ddr4-2133-x8-4gb"), path, "ramulator")
    >>> result.reads, result.writes, cpu_accesses
    (4096, 0, 0)
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from hdeem_watch.dram.command_set import ControllerResult
from hdeem_watch.dram.controller import simulate, simulate_requests
from hdeem_watch.dram.memspec import MemSpec
from hdeem_watch.dram.progress import ProgressCallback
from hdeem_watch.dram.request_traces import CacheConfig, map_file, read_request_trace
from hdeem_watch.dram.uniform_parser import UniformParser, uniform_lines


def simulate_trace(spec: MemSpec, path: str | Path, fmt: str, *, cache: CacheConfig | None = None,
                   progress: ProgressCallback | None = None, **options: Any) -> tuple[ControllerResult, int]:
    """Simulate the requests of a trace file (see the module doc).

    Args:
        spec: memspec of the channel.
        path: the trace.
        fmt: one of :data:`hdeem_watch.dram.request_traces.FORMATS`.
        cache: the last-level cache of CPU traces (``pinatrace``, ``lackey``).
        progress: told how far reading a CPU trace and the controller model are
            (:mod:`hdeem_watch.dram.progress`).
        options: :func:`hdeem_watch.dram.controller.simulate`'s keyword arguments.

    Returns:
        ``(result, cpu_accesses)``: the statistics, and the CPU accesses before the cache filter
        (0 for DRAM-level traces).

    Raises:
        InputError: ``file:line`` and what was wrong, for a malformed line; or a bad format or option.
    """
    if fmt in ("ramulator", "ramulator2") and Path(path).is_file():
        text = uniform_lines(map_file(path, populate=False))  # the worker touches its own chunks
        if text is not None:
            parsers: list[UniformParser] = []  # made where it is used (the worker): its own work arrays

            def requests(lo: int, hi: int) -> tuple[np.ndarray, np.ndarray]:
                if not parsers:
                    parsers.append(UniformParser(text.shape[1] - 1, fmt))
                addresses = np.empty(hi - lo, dtype=np.uint64)
                writes = np.empty(hi - lo, dtype=bool)
                if not parsers[0].parse_range(text, lo, hi, addresses, writes):
                    raise _NotUniform(lo)
                return addresses, writes

            try:
                return simulate_requests(spec, text.shape[0], requests, progress=progress, **options), 0
            except _NotUniform:
                pass  # mixed line lengths or a malformed line: the general reader names it
    trace = read_request_trace(path, fmt, cache=cache, progress=progress)
    return simulate(spec, trace.addresses, trace.is_write, progress=progress, **options), trace.cpu_accesses


class _NotUniform(Exception):
    """A block of the trace is not lines of one length in the format (raised in the pipeline)."""
