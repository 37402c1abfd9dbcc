"""Benchmark schedules: which kernels run with how many threads, how often.

A schedule is a flat list of :class:`RunSpec`, one per run, in the order the runs happen:
kernels × thread counts × repetitions (``repeat`` passes over the arrays per run). The thread
specification is a small language, comma-separated items that are either a count (``4``) or a
range ``start-stop[:step]`` with an inclusive stop (``4-24:4`` = 4, 8, 12, 16, 20, 24).

Example:
    >>> parse_threads("1,2,4-12:4")
    [1, 2, 4, 8, 12]
    >>> [(r.kernel, r.threads) for r in sweep(["read", "copy"], "1,2", 1 << 20, 3)]
    [('read', 1), ('read', 2), ('copy', 1), ('copy', 2)]
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from hdeem_watch.errors import InputError

#: The STREAM-like kernels of DESIGN.md §3 (same names as ``hdeem_watch.dram.kernels.KERNELS``).
KERNELS: tuple[str, ...] = ("read", "assign", "scale", "add", "triad", "copy", "selfscale")
#: The compute-only kernel: cores busy in registers, DRAM idle (static power, baselines).
IDLE_KERNEL = "idle"
#: Workloads a calibration never fits (``hdeem_watch.dram.kernels.HOLDOUT_KERNELS``): GUPS-like random
#: reads, a dependent pointer chase, 2- and 4-line strides, a 3:1 read/write mix; announced with
#: ``metadata.holdout = true`` the daemon predicts them with the fit from before and never fits them.
HOLDOUT_KERNELS: tuple[str, ...] = ("gups", "chase", "stride2", "stride4", "mix31")
#: Every kernel name the bench accepts, after alias resolution.
ALL_KERNELS: tuple[str, ...] = (*KERNELS, IDLE_KERNEL, *HOLDOUT_KERNELS)
#: Accepted spellings that map onto a canonical name.
KERNEL_ALIASES: dict[str, str] = {"addition": "add"}

#: Upper bound on a thread count, to catch typos such as ``1-2400`` early.
MAX_THREADS = 4096


@dataclass(frozen=True)
class RunSpec:
    """One benchmark run: ``repeat`` passes of ``kernel`` over arrays of ``elements`` doubles.

    Attributes:
        kernel: canonical kernel name (one of :data:`ALL_KERNELS`).
        threads: number of worker threads, each pinned to its own CPU.
        elements: length of each array in doubles (stride 8: ``elements // 8`` lines per array).
        repeat: number of passes over the arrays in this run.
    """

    kernel: str
    threads: int
    elements: int
    repeat: int

    def to_dict(self) -> dict[str, object]:
        """Return the run's parameters as a JSON-ready dict."""
        return {"kernel": self.kernel, "threads": self.threads, "elements": self.elements,
                "repeat": self.repeat}


def canonical_kernel(name: str) -> str:
    """Return the canonical kernel name for ``name`` (case-insensitive, aliases resolved).

    Raises:
        InputError: the name is not a known kernel.
    """
    key = name.strip().lower()
    key = KERNEL_ALIASES.get(key, key)
    if key not in ALL_KERNELS:
        raise InputError(f"kernel {name!r}: unknown; expected one of {', '.join(ALL_KERNELS)} "
                         "(or 'addition')")
    return key


def parse_kernels(spec: str | Iterable[str]) -> list[str]:
    """Parse a kernel list (``"read,copy"``, ``"all"`` or an iterable of names).

    ``all`` expands to the seven STREAM-like kernels; ``all+idle`` adds the idle kernel; ``holdout``
    the hold-out kernels (:data:`HOLDOUT_KERNELS`).

    Raises:
        InputError: an empty list or an unknown name.
    """
    items = spec.split(",") if isinstance(spec, str) else list(spec)
    out: list[str] = []
    for item in items:
        word = item.strip().lower()
        if not word:
            continue
        if word == "all":
            out.extend(KERNELS)
        elif word == "all+idle":
            out.extend((*KERNELS, IDLE_KERNEL))
        elif word == "holdout":
            out.extend(HOLDOUT_KERNELS)
        else:
            out.append(canonical_kernel(word))
    if not out:
        raise InputError(f"--kernels {spec!r}: empty; expected a comma-separated list such as 'read,copy'")
    return out


def _parse_int(text: str, whole: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise InputError(f"--threads {whole!r}: {text!r} is not an integer; "
                         "expected items like 4 or 4-24:4") from None
    return value


def parse_threads(spec: str) -> list[int]:
    """Parse a thread-count specification into a list of counts, in the given order.

    Items are separated by commas; each is ``N`` or ``A-B`` or ``A-B:S`` (inclusive range with step
    S, default 1). Duplicates are kept only once (first occurrence wins).

    Args:
        spec: e.g. ``"1,2,4-24:4"``.

    Returns:
        The thread counts, e.g. ``[1, 2, 4, 8, 12, 16, 20, 24]``.

    Raises:
        InputError: empty spec, non-integers, counts < 1 or > MAX_THREADS, a descending range or a
            step < 1.
    """
    whole = spec
    if not isinstance(spec, str) or not spec.strip():
        raise InputError(f"--threads {whole!r}: empty; expected items like 1,2,4-24:4")
    counts: list[int] = []
    for raw in spec.split(","):
        item = raw.strip()
        if not item:
            raise InputError(f"--threads {whole!r}: empty item; expected items like 1,2,4-24:4")
        step = 1
        if ":" in item:
            item, step_text = item.split(":", 1)
            step = _parse_int(step_text.strip(), whole)
            if step < 1:
                raise InputError(f"--threads {whole!r}: step {step} must be >= 1")
            if "-" not in item:
                raise InputError(f"--threads {whole!r}: a step needs a range (A-B:S)")
        if "-" in item:
            start_text, stop_text = item.split("-", 1)
            start = _parse_int(start_text.strip(), whole)
            stop = _parse_int(stop_text.strip(), whole)
            if stop < start:
                raise InputError(f"--threads {whole!r}: range {start}-{stop} is descending; "
                                 "expected A-B with A <= B")
            values = list(range(start, stop + 1, step))
        else:
            values = [_parse_int(item, whole)]
        for value in values:
            if value < 1 or value > MAX_THREADS:
                raise InputError(f"--threads {whole!r}: {value} threads is out of range; "
                                 f"expected 1..{MAX_THREADS}")
            if value not in counts:
                counts.append(value)
    return counts


def sweep(kernels: str | Iterable[str], threads_spec: str | Iterable[int], elements: int,
          repeat: int) -> list[RunSpec]:
    """Build the run list: every kernel × every thread count (kernel-major order).

    Args:
        kernels: kernel names (or a comma-separated string; see :func:`parse_kernels`).
        threads_spec: a thread specification string (see :func:`parse_threads`) or counts.
        elements: doubles per array (>= 8, i.e. at least one 64-byte line).
        repeat: passes per run (>= 1).

    Raises:
        InputError: any parameter out of range.
    """
    names = parse_kernels(kernels)
    if isinstance(threads_spec, str):
        counts = parse_threads(threads_spec)
    else:
        counts = [int(t) for t in threads_spec]
        if not counts or any(t < 1 or t > MAX_THREADS for t in counts):
            raise InputError(f"threads {counts!r}: expected counts in 1..{MAX_THREADS}")
    if int(elements) < 8:
        raise InputError(f"--elements {elements}: too small; expected at least 8 doubles (one line)")
    if int(repeat) < 1:
        raise InputError(f"--repeat {repeat}: expected at least 1")
    return [RunSpec(kernel=k, threads=t, elements=int(elements), repeat=int(repeat))
            for k in names for t in counts]
