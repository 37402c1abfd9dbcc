"""Replay source: plays back the daemon's recordings (CSV) at recorded or faster speed.

Recording format v1 (UTF-8 CSV, one sample per line, any channel order)::

    # hdeem-watch recording v1
    # node: taurusi6262
    # rate_hz: BLADE=1000 CPU0=100 DDR_AB=100
    t_ns,channel,power_w
    1619682395759000000,BLADE,101.125
    1619682395760000000,DDR_AB,nan

The first line names the format and version; further ``# key: value`` lines are metadata (``rate_hz``
gives nominal rates, otherwise the median sample spacing is used); then the header
``t_ns,channel,power_w``; ``t_ns`` = wall-clock integer ns at the end of the sample's interval,
``power_w`` in W (``nan`` or empty = unknown). Timestamps must increase strictly per channel.

Checked at load, one line naming file, line, field and value (exit 2 in the CLI): ``t_ns`` an integer
in ``0 .. 2**63 - 1``; ``power_w`` finite (``inf`` is not a reading), ``>= 0`` and at most
:data:`MAX_POWER_W`; channel names of letters, digits and ``_`` (they become topic and metric
names); ``rate_hz`` finite and > 0. Unknown samples (``nan``) are played as NaN with status
``"stale"``, counted in the batch's ``gaps`` and left out of ``energy_j`` — never taken as 0 W.

Playback: the recording's time runs ``speed`` × the injected clock since :meth:`ReplaySource.open`;
published timestamps are ``wall clock at open + offset in the recording`` (the rates hold in
timestamp time, as in the sim), or the recorded timestamps with ``restamp=False``. With ``loop`` the
recording repeats (each pass shifted by its length plus one sample period).

Example:
    >>> import tempfile, os, numpy as np
    >>> path = os.path.join(tempfile.mkdtemp(), "r.csv")
    >>> write_recording(path, {"DDR_AB": (np.array([10, 20, 30]), np.array([1.0, 1.5, 2.0]))})
    3
    >>> read_recording(path).channels["DDR_AB"][1].tolist()
    [1.0, 1.5, 2.0]
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

import numpy as np

from hdeem_watch.errors import InputError
from hdeem_watch.sources.base import (
    STATUS_OK,
    STATUS_STALE,
    ChannelInfo,
    ChannelKind,
    QuietLimit,
    SourceBatch,
    normalise_channel_name,
)

MAGIC = "# hdeem-watch recording v"
#: The largest power a recorded sample may have (W): no sensor of one node reads more.
MAX_POWER_W = 100_000.0
#: Timestamps are int64 nanoseconds.
MAX_T_NS = 2**63 - 1
_CHANNEL = re.compile(r"^[A-Z0-9_]+$")
VERSION = 1
HEADER = "t_ns,channel,power_w"

Samples = Mapping[str, tuple[np.ndarray, np.ndarray]]


@dataclass
class Recording:
    """A loaded recording: per channel ``(t_ns int64, power_w float64)``, metadata, rates."""

    channels: dict[str, tuple[np.ndarray, np.ndarray]]
    meta: dict[str, str] = field(default_factory=dict)
    rate_hz: dict[str, float] = field(default_factory=dict)

    @property
    def t_first_ns(self) -> int:
        """The earliest sample time."""
        return min(int(t[0]) for t, _ in self.channels.values() if len(t))

    @property
    def t_last_ns(self) -> int:
        """The latest sample time."""
        return max(int(t[-1]) for t, _ in self.channels.values() if len(t))


def _kind(name: str) -> ChannelKind:
    if name == "BLADE":
        return "blade"
    return "dram" if name.startswith(("DDR", "DRAM")) else "cpu"


def write_header(fh: TextIO, node: str | None = None, rate_hz: Mapping[str, float] | None = None) -> None:
    """Write the format line, metadata and column header."""
    fh.write(f"{MAGIC}{VERSION}\n")
    if node:
        fh.write(f"# node: {node}\n")
    if rate_hz:
        fh.write("# rate_hz: " + " ".join(f"{k}={v:g}" for k, v in rate_hz.items()) + "\n")
    fh.write(HEADER + "\n")


def write_rows(fh: TextIO, samples: Samples) -> int:
    """Append samples (merged in time order); returns the number of rows."""
    rows: list[tuple[int, str, float]] = []
    for name, (t, p) in samples.items():
        rows.extend(zip((int(x) for x in t), [name] * len(t), (float(x) for x in p)))
    rows.sort(key=lambda r: r[0])
    fh.writelines(f"{t},{name},{'nan' if math.isnan(p) else repr(p)}\n" for t, name, p in rows)
    return len(rows)


def write_recording(path: str | Path, samples: Samples | Iterable[SourceBatch], *, node: str | None = None,
                    rate_hz: Mapping[str, float] | None = None) -> int:
    """Write a v1 recording from ``{channel: (t_ns, power_w)}`` or from a sequence of batches.

    Returns:
        The number of sample rows written.
    """
    with open(path, "w", encoding="utf-8") as fh:
        write_header(fh, node=node, rate_hz=rate_hz)
        if isinstance(samples, Mapping):
            return write_rows(fh, samples)
        return sum(write_rows(fh, batch.samples) for batch in samples)


class RecordingWriter:
    """Append batches to a recording as they come (e.g. the daemon's ``--record FILE``).

    Example:
        >>> import tempfile, os
        >>> w = RecordingWriter(os.path.join(tempfile.mkdtemp(), "r.csv"), node="n1")
        >>> w.close()
    """

    def __init__(self, path: str | Path, *, node: str | None = None,
                 rate_hz: Mapping[str, float] | None = None) -> None:
        self._fh = open(path, "w", encoding="utf-8")  # noqa: SIM115 - kept open across batches
        write_header(self._fh, node=node, rate_hz=rate_hz)
        self.rows = 0

    def write_batch(self, batch: SourceBatch) -> None:
        """Append one batch's samples."""
        self.rows += write_rows(self._fh, batch.samples)

    def flush(self) -> None:
        """Flush to the OS."""
        self._fh.flush()

    def close(self) -> None:
        """Flush and close (idempotent)."""
        if not self._fh.closed:
            self._fh.close()


def parse_recording(lines: Iterable[str], where: str = "recording") -> Recording:
    """Parse a v1 recording.

    Raises:
        InputError: ``<where>:<line>: ...`` for a wrong version, header, column count, time or value.
    """
    it = iter(enumerate(lines, 1))
    first = next(it, (1, ""))[1].strip()
    if not first.startswith(MAGIC):
        raise InputError(f"{where}:1: expected {MAGIC}{VERSION!r}, got {first[:60]!r}")
    version = first[len(MAGIC):].strip()
    if version != str(VERSION):
        raise InputError(f"{where}:1: recording version {version!r} not supported; expected {VERSION}")
    meta: dict[str, str] = {}
    data: dict[str, tuple[list[int], list[float]]] = {}
    header_seen = False
    for lineno, raw in it:
        line = raw.strip()
        if not line:
            continue
        if line.startswith("#"):
            key, _, value = line[1:].partition(":")
            meta[key.strip()] = value.strip()
            continue
        if not header_seen:
            if line.replace(" ", "") != HEADER:
                raise InputError(f"{where}:{lineno}: expected the header {HEADER!r}, got {line[:60]!r}")
            header_seen = True
            continue
        parts = line.split(",")
        if len(parts) != 3:
            raise InputError(f"{where}:{lineno}: expected 3 fields t_ns,channel,power_w, got {len(parts)}")
        try:
            t = int(parts[0])
        except ValueError:
            raise InputError(f"{where}:{lineno}: t_ns {parts[0][:40]!r} is not an integer (ns)") from None
        if not 0 <= t <= MAX_T_NS:
            raise InputError(f"{where}:{lineno}: t_ns {t} is out of range; expected 0 .. 2**63 - 1 ns")
        try:
            p = float(parts[2]) if parts[2].strip() else math.nan
        except ValueError:
            raise InputError(f"{where}:{lineno}: power_w {parts[2][:40]!r} is not a number") from None
        if math.isinf(p):
            raise InputError(f"{where}:{lineno}: power_w {parts[2].strip()!r} is not finite; write nan (or "
                             "nothing) for an unknown sample")
        if p < 0:
            raise InputError(f"{where}:{lineno}: power_w {p} is negative")
        if p > MAX_POWER_W:
            raise InputError(f"{where}:{lineno}: power_w {p:g} is implausible; expected at most {MAX_POWER_W:g} W")
        name = normalise_channel_name(parts[1])
        if not _CHANNEL.match(name):
            raise InputError(f"{where}:{lineno}: channel {parts[1].strip()[:40]!r} is not a valid name; expected "
                             "letters, digits and '_' (e.g. DDR_AB)")
        ts, ps = data.setdefault(name, ([], []))
        if ts and t <= ts[-1]:
            raise InputError(f"{where}:{lineno}: t_ns {t} of {name} does not increase (previous {ts[-1]})")
        ts.append(t)
        ps.append(p)
    if not header_seen or not data:
        raise InputError(f"{where}: no samples; expected the header {HEADER!r} and rows")
    channels = {n: (np.array(ts, dtype=np.int64), np.array(ps, dtype=float)) for n, (ts, ps) in data.items()}
    rates: dict[str, float] = {}
    for item in meta.get("rate_hz", "").split():
        key, _, value = item.partition("=")
        try:
            rate = float(value)
        except ValueError:
            raise InputError(f"{where}: metadata rate_hz {item[:60]!r}; expected NAME=number") from None
        if not (math.isfinite(rate) and rate > 0):
            raise InputError(f"{where}: metadata rate_hz {item[:60]!r}: the rate must be a finite number > 0 (Sa/s)")
        rates[normalise_channel_name(key)] = rate
    for name, (times, _) in channels.items():
        if name not in rates:
            rates[name] = 1e9 / float(np.median(np.diff(times))) if len(times) > 1 else 1.0
    return Recording(channels, meta, rates)


def read_recording(path: str | Path) -> Recording:
    """Load a recording file (see :func:`parse_recording`)."""
    try:
        with open(path, encoding="utf-8") as fh:
            return parse_recording(fh, where=str(path))
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a UTF-8 text recording") from None


class ReplaySource:
    """Plays a recording back as a source.

    Args:
        path: the recording.
        speed: recorded seconds per clock second (≥ 1 plays faster).
        loop: start again at the end.
        restamp: publish ``wall at open + recorded offset`` (default) or the recorded timestamps.
        clock, wall_clock: injectable clocks (ns).
    """

    kind = "replay"

    def __init__(self, path: str | Path, speed: float = 1.0, loop: bool = False, restamp: bool = True,
                 clock: Callable[[], int] = time.monotonic_ns, wall_clock: Callable[[], int] = time.time_ns) -> None:
        if not (isinstance(speed, int | float) and math.isfinite(speed) and speed > 0):
            raise InputError(f"replay: speed = {speed!r}; expected a finite number > 0")
        self.path = Path(path)
        self.speed = float(speed)
        self.loop = loop
        self.restamp = restamp
        self._clock, self._wall = clock, wall_clock
        self.recording = read_recording(self.path)
        rec = self.recording
        self._t0 = rec.t_first_ns
        self._rel = {n: t - self._t0 for n, (t, _) in rec.channels.items()}
        max_period = max(round(1e9 / r) for r in rec.rate_hz.values())
        self.length_ns = rec.t_last_ns - self._t0 + max_period
        self._open_mono = 0
        self._open_wall = 0
        self._cursor = 0
        self._energy_j: dict[str, float] = {}
        self._state = "closed"

    def channels(self) -> list[ChannelInfo]:
        """The recorded channels with their rates."""
        return [ChannelInfo(n, self.recording.rate_hz[n], _kind(n)) for n in self.recording.channels]

    def open(self) -> None:
        """Start playback at the recording's first sample."""
        self._open_mono = int(self._clock())
        self._open_wall = int(self._wall())
        self._cursor = 0
        self._energy_j = dict.fromkeys(self.recording.channels, math.nan)
        self._state = "ok"

    def close(self) -> None:
        """Stop playback (idempotent)."""
        self._state = "closed"

    @property
    def quiet_limit(self) -> QuietLimit:
        """A recording loses nothing however rarely it is read: every recorded sample stays in the file."""
        return QuietLimit(math.inf)

    def health(self) -> str:
        """``"ok"``, ``"ended"`` (played once, no loop) or ``"closed"``."""
        return self._state

    def position_ns(self) -> int:
        """Where playback is, as a recorded timestamp (the end of what :meth:`poll` delivered)."""
        return self._t0 + self._cursor

    def played_ns(self, recorded_t_ns: int) -> int:
        """A recorded timestamp on the played-back axis (the published samples' times, first pass)."""
        return int(recorded_t_ns) - self._t0 + (self._open_wall if self.restamp else self._t0)

    def poll(self) -> SourceBatch:
        """The recorded samples whose (played-back) time has come since the last poll."""
        now = int(self._clock())
        cursor = round((now - self._open_mono) * self.speed)
        if not self.loop:
            cursor = min(cursor, self.length_ns)
        a, b = self._cursor, max(self._cursor, cursor)
        self._cursor = b
        samples: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        status: dict[str, str] = {}
        gaps: dict[str, int] = {}
        for name, (_, power) in self.recording.channels.items():
            rel = self._rel[name]
            ts, ps = [], []
            last_pass = (b - 1) // self.length_ns if self.loop else 0
            for k in range(a // self.length_ns, last_pass + 1):
                lo, hi = a - k * self.length_ns, b - k * self.length_ns   # samples at [a, b) in played time
                i, j = np.searchsorted(rel, lo, side="left"), np.searchsorted(rel, hi, side="left")
                ts.append(rel[i:j] + k * self.length_ns)
                ps.append(power[i:j])
            t = np.concatenate(ts) if ts else np.zeros(0, dtype=np.int64)
            p = np.concatenate(ps) if ps else np.zeros(0)
            base = self._open_wall if self.restamp else self._t0
            samples[name] = (t + base, p)
            finite = p[np.isfinite(p)]
            if len(finite):  # a channel with no known sample yet has an unknown energy, not 0 J
                known = self._energy_j[name]
                self._energy_j[name] = (0.0 if math.isnan(known) else known) + float(finite.sum()) / \
                    self.recording.rate_hz[name]
            unknown = len(p) - len(finite)   # unknown samples: marked, counted missing, not in the energy
            status[name] = STATUS_STALE if unknown else STATUS_OK
            if unknown:
                gaps[name] = unknown
        if not self.loop and b >= self.length_ns:
            self._state = "ended"
        return SourceBatch(now, int(self._wall()), samples, dict(self._energy_j), status, gaps)
