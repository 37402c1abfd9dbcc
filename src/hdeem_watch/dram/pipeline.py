"""Run the preparing stage of a chunked computation ahead of its sequential stage.

:func:`hdeem_watch.dram.controller.simulate` serves a long stream in chunks: preparing a chunk
(decoding, service order, row outcomes) does not depend on the chunks before it, timing it does.
:func:`prepared` yields ``prepare(0)``, ``prepare(1)``, ... while the caller works on the previous
one, in one of three ways:

- ``"process"``: a forked worker process prepares the chunks and hands the arrays over in shared
  memory (a ring of slots; a pipe carries each chunk's layout and the slot's release). No lock is
  shared, so both CPU cores work all the time (threads contend for Python's lock between numpy
  calls: hundreds of hand-overs per chunk). Used only where forking is safe: POSIX, one thread in
  the process. The arrays yielded are views of a slot, valid until the next chunk is asked for.
- ``"thread"``: one worker thread (numpy releases the lock inside its loops).
- ``"inline"``: no overlap.

A chunk's result is a tuple of arrays, ``None`` and dataclasses of arrays (one level).

:func:`split_work` fills arrays in two halves at once (a thread for the first).

Example:
    >>> import numpy as np
    >>> [int(a.sum()) for (a,) in prepared(lambda i: (np.arange(i + 3),), 3, "thread")]
    [3, 6, 10]
"""

from __future__ import annotations

import contextlib
import dataclasses
import mmap
import os
import pickle
import signal
import struct
import threading
import traceback
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

#: Chunks a worker process may prepare ahead of the consumer.
SLOTS = 3
_ALIGN = 64


def process_safe() -> bool:
    """Whether a worker process can be forked here (POSIX fork, no other thread running)."""
    return hasattr(os, "fork") and threading.active_count() == 1


def prepared(prepare: Callable[[int], tuple[Any, ...]], pieces: int, mode: str = "thread",
             slot_bytes: int = 0) -> Iterator[tuple[Any, ...]]:
    """``prepare(i)`` for ``i < pieces``, computed ahead of the consumer.

    Args:
        prepare: the preparing stage.
        pieces: chunks.
        mode: ``"process"``, ``"thread"`` or ``"inline"`` (see the module doc); ``"process"``
            falls back to a thread where forking is not safe.
        slot_bytes: shared memory per slot (``"process"``); a chunk that does not fit is pickled
            through the pipe instead.
    """
    if mode == "process" and process_safe() and pieces > 1:
        yield from _in_process(prepare, pieces, max(slot_bytes, 1 << 16))
    elif mode in ("thread", "process") and pieces > 1:
        with ThreadPoolExecutor(max_workers=1) as pool:
            pending = pool.submit(prepare, 0)
            for i in range(pieces):
                result = pending.result()
                if i + 1 < pieces:
                    pending = pool.submit(prepare, i + 1)
                yield result
    else:
        for i in range(pieces):
            yield prepare(i)


def _flatten(result: tuple[Any, ...]) -> tuple[list[np.ndarray | None], list[Any]]:
    """The arrays of a result and how to rebuild it: ``("a", k)`` array ``k``, ``("d", type, names, ks)``."""
    arrays: list[np.ndarray | None] = []
    layout: list[Any] = []
    for item in result:
        if dataclasses.is_dataclass(item) and not isinstance(item, type):
            names = [f.name for f in dataclasses.fields(item)]
            layout.append(("d", type(item), names, list(range(len(arrays), len(arrays) + len(names)))))
            arrays.extend(getattr(item, name) for name in names)
        else:
            layout.append(("a", len(arrays)))
            arrays.append(item)
    return arrays, layout


def _rebuild(arrays: list[np.ndarray | None], layout: list[Any]) -> tuple[Any, ...]:
    items: list[Any] = []
    for entry in layout:
        if entry[0] == "a":
            items.append(arrays[entry[1]])
        else:
            _, kind, names, keys = entry
            items.append(kind(**{name: arrays[k] for name, k in zip(names, keys)}))
    return tuple(items)


def _send(fd: int, message: Any) -> None:
    data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
    view = memoryview(struct.pack("<Q", len(data)) + data)
    while view:
        view = view[os.write(fd, view):]


def _receive_exact(fd: int, size: int) -> bytes:
    parts = []
    while size:
        part = os.read(fd, min(size, 1 << 20))
        if not part:
            raise EOFError("pipeline worker ended early")
        parts.append(part)
        size -= len(part)
    return b"".join(parts)


def _receive(fd: int) -> Any:
    (size,) = struct.unpack("<Q", _receive_exact(fd, 8))
    return pickle.loads(_receive_exact(fd, size))


def _worker(prepare: Callable[[int], tuple[Any, ...]], pieces: int, shared: mmap.mmap, slot_bytes: int,
            ready_w: int, free_r: int) -> None:
    """The child: prepare every chunk into the next free slot, announce its layout."""
    buffer = np.frombuffer(shared, dtype=np.uint8)
    for i in range(pieces):
        if i >= SLOTS:
            _receive_exact(free_r, 1)  # the consumer released a slot
        arrays, layout = _flatten(prepare(i))
        base = (i % SLOTS) * slot_bytes
        offset = 0
        meta: list[tuple[str, int, int] | None] = []
        total = sum(-(-a.nbytes // _ALIGN) * _ALIGN for a in arrays if a is not None)
        if total > slot_bytes:  # does not fit: through the pipe
            _send(ready_w, ("pickled", arrays, layout))
            continue
        for array in arrays:
            if array is None:
                meta.append(None)
                continue
            array = np.ascontiguousarray(array).ravel()
            buffer[base + offset:base + offset + array.nbytes] = array.view(np.uint8)
            meta.append((array.dtype.str, array.size, base + offset))
            offset += -(-array.nbytes // _ALIGN) * _ALIGN
        _send(ready_w, ("shared", meta, layout))


def _in_process(prepare: Callable[[int], tuple[Any, ...]], pieces: int, slot_bytes: int) -> Iterator[tuple[Any, ...]]:
    shared = mmap.mmap(-1, SLOTS * slot_bytes)  # anonymous, shared with the child
    ready_r, ready_w = os.pipe()
    free_r, free_w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the worker: never returns
        code = 0
        try:
            os.close(ready_r)
            os.close(free_w)
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            try:
                _worker(prepare, pieces, shared, slot_bytes, ready_w, free_r)
            except BaseException as error:  # reported to the parent, which raises it
                _send(ready_w, ("error", error, traceback.format_exc()))
        except BaseException:  # the pipe is gone: the parent is gone too
            code = 1
        finally:
            os._exit(code)
    os.close(ready_w)
    os.close(free_r)
    buffer = np.frombuffer(shared, dtype=np.uint8)
    finished = False
    try:
        for i in range(pieces):
            message = _receive(ready_r)
            if message[0] == "error":
                if isinstance(message[1], Exception):
                    raise message[1]
                raise RuntimeError(f"pipeline worker failed:\n{message[2]}")
            if message[0] == "pickled":
                arrays = message[1]
            else:
                arrays = [None if m is None else buffer[m[2]:m[2] + m[1] * np.dtype(m[0]).itemsize].view(m[0])
                          for m in message[1]]
            yield _rebuild(arrays, message[2])
            if i + SLOTS < pieces:
                # the consumer is done with chunk i: its slot is free (unless the worker stopped:
                # then its error message follows)
                with contextlib.suppress(BrokenPipeError):
                    os.write(free_w, b"\0")
        finished = True
    finally:
        os.close(ready_r)
        os.close(free_w)
        if not finished:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
        del buffer
        with contextlib.suppress(BufferError):  # a caller still holds a view: the mapping goes with it
            shared.close()


def split_work(work: Callable[[int, int, tuple[np.ndarray, ...]], bool], count: int,
               dtypes: tuple[Any, ...]) -> tuple[np.ndarray, ...] | None:
    """Fill arrays of ``count`` entries in two halves at once (the first in a thread); ``None`` if a half failed.

    ``work(lo, hi, out)`` fills ``out`` (one array per dtype, ``hi - lo`` entries each) for the
    entries ``lo:hi`` and returns whether it succeeded. Meant for long numpy operations (each
    holds the lock only briefly), e.g. parsing a trace in blocks of 65536 lines.
    """
    half = count // 2
    outputs = tuple(np.empty(count, dtype=d) for d in dtypes)
    with ThreadPoolExecutor(max_workers=1) as pool:
        first = pool.submit(work, 0, half, tuple(o[:half] for o in outputs))
        second = work(half, count, tuple(o[half:] for o in outputs))
        return outputs if first.result() and second else None
