"""Counters recorded beside a recording, and played back with it (``counters = "replay"``).

With ``record_file`` set and a counter source on, every counter snapshot the daemon reads is
appended to ``<record_file>.counters.jsonl``: a header line, then one JSON object per snapshot::

    {"format": "hdeem-watch counters v1", "kind": "sim", "generation": "haswell-ep", "ranks": 2,
     "refresh_complete": false, "channels": [{"name": "S0.imc0", "socket": 0, "sensor": "DDR_AB"}, ...]}
    {"t_ns": 1700000001000000000, "counts": {"S0.imc0": {"act": 1.0e6, ...}}, "unknown": {}}

``t_ns`` is on the recording's sample axis (the same clock as its ``t_ns`` column), so a replay
(:class:`CounterReplay`) maps it with the samples: at each read it returns the recorded counts at
the replay's position (interpolated between recorded snapshots, never past the last one), stamped
on the played-back axis. A looping replay has no counter replay (the counts would go back).

Example:
    >>> import os, tempfile
    >>> from hdeem_watch.counters.event_tables import TABLES
    >>> path = os.path.join(tempfile.mkdtemp(), "r.csv.counters.jsonl")
    >>> rec = CounterRecorder(path, kind="sim", table=TABLES["haswell-ep"], ranks=2, channels=())
    >>> rec.write(CounterSnapshot(5, {"S0.imc0": {"act": 1.0}})); rec.close()
    >>> read_counter_recording(path)[1][0].counts
    {'S0.imc0': {'act': 1.0}}
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

from hdeem_watch.counters.event_tables import TABLES, EventTable
from hdeem_watch.counters.source import CounterChannel, CounterSnapshot, interpolate
from hdeem_watch.errors import InputError

FORMAT = "hdeem-watch counters v1"
SUFFIX = ".counters.jsonl"


@runtime_checkable
class Looping(Protocol):
    """A power source that may start again at its end (a looping replay): its counters cannot follow."""

    loop: bool


def counters_path(recording: str | Path) -> Path:
    """The counters file beside a recording."""
    return Path(f"{recording}{SUFFIX}")


class CounterRecorder:
    """Append counter snapshots to a ``.counters.jsonl`` file (see the module docstring)."""

    def __init__(self, path: str | Path, *, kind: str, table: EventTable, ranks: int,
                 channels: Sequence[CounterChannel]) -> None:
        self._fh = open(path, "w", encoding="utf-8")  # noqa: SIM115 - kept open across snapshots
        header = {"format": FORMAT, "kind": kind, "generation": table.generation, "ranks": int(ranks),
                  "refresh_complete": table.refresh_complete,
                  "channels": [{"name": c.name, "socket": c.socket, "sensor": c.sensor} for c in channels]}
        self._fh.write(json.dumps(header) + "\n")

    def write(self, snapshot: CounterSnapshot) -> None:
        """Append one snapshot (NaN as null)."""
        counts = {c: {r: (v if math.isfinite(v) else None) for r, v in roles.items()}
                  for c, roles in snapshot.counts.items()}
        self._fh.write(json.dumps({"t_ns": snapshot.t_ns, "counts": counts, "unknown": snapshot.unknown}) + "\n")

    def flush(self) -> None:
        """Flush to the OS."""
        self._fh.flush()

    def close(self) -> None:
        """Flush and close (idempotent)."""
        if not self._fh.closed:
            self._fh.close()


def read_counter_recording(path: str | Path) -> tuple[dict[str, Any], list[CounterSnapshot]]:
    """The header and the time-ordered snapshots of a counters file.

    Raises:
        InputError: unreadable, not this format, or a malformed line (naming file and line).
    """
    try:
        lines = Path(path).read_text(encoding="utf-8").splitlines()
    except OSError as error:
        raise InputError(f"{path}: cannot read the recorded counters ({error.strerror})") from None
    if not lines:
        raise InputError(f"{path}: empty; expected a '{FORMAT}' header line")
    try:
        header = json.loads(lines[0])
    except json.JSONDecodeError:
        header = None
    if not isinstance(header, dict) or header.get("format") != FORMAT or header.get("generation") not in TABLES:
        raise InputError(f"{path}:1: expected a '{FORMAT}' header with a known generation")
    snapshots: list[CounterSnapshot] = []
    for number, line in enumerate(lines[1:], start=2):
        try:
            data = json.loads(line)
            t_ns = data["t_ns"]
            counts = {str(c): {str(r): math.nan if v is None else float(v) for r, v in roles.items()}
                      for c, roles in data["counts"].items()}
            unknown = {str(c): {str(r): int(v) for r, v in roles.items()} for c, roles in data.get("unknown", {}).items()}
        except (json.JSONDecodeError, KeyError, TypeError, ValueError, AttributeError):
            raise InputError(f"{path}:{number}: expected a snapshot {{t_ns, counts, unknown}}") from None
        if not isinstance(t_ns, int) or (snapshots and t_ns < snapshots[-1].t_ns):
            raise InputError(f"{path}:{number}: t_ns = {t_ns!r}; expected integer ns, not decreasing")
        snapshots.append(CounterSnapshot(t_ns, counts, unknown))
    return header, snapshots


class CounterReplay:
    """The recorded counters at a replay's position (a :class:`~hdeem_watch.counters.source.CounterSource`).

    Args:
        recording: the samples recording (its counters file is ``<recording>.counters.jsonl``).
        source: the replay source playing it (``position_ns``, ``played_ns``, ``loop``).

    Raises:
        InputError: no or a malformed counters file, or a looping replay.
    """

    kind = "replay"

    def __init__(self, recording: str | Path, source: Any) -> None:
        if isinstance(source, Looping) and source.loop:
            raise InputError("counters = 'replay' cannot follow a looping replay (the counts would go back)")
        header, self._snapshots = read_counter_recording(counters_path(recording))
        if not self._snapshots:
            raise InputError(f"{counters_path(recording)}: no snapshot recorded")
        self.source = source
        self.table = TABLES[header["generation"]]
        self.ranks = int(header.get("ranks") or 2)
        self._channels = tuple(CounterChannel(str(c["name"]), int(c.get("socket", 0)), c.get("sensor"))
                               for c in header.get("channels", []))

    def channels(self) -> tuple[CounterChannel, ...]:
        """The recorded channels."""
        return self._channels

    def read(self) -> CounterSnapshot:
        """The recorded counts at the replay's position, on the played-back axis."""
        position = min(self.source.position_ns(), self._snapshots[-1].t_ns)
        recorded = interpolate(self._snapshots, position)
        return CounterSnapshot(self.source.played_ns(recorded.t_ns), recorded.counts, recorded.unknown)

    def close(self) -> None:
        """Nothing to release."""
