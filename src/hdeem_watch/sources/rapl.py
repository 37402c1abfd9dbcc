"""RAPL DRAM source: Linux powercap zones whose ``name`` is ``dram``.

RAPL reports DRAM energy **per socket**, not per DIMM pair: the zone under package ``intel-rapl:N``
becomes channel ``DRAM<N>``. On the modelled Haswell-EP node ``DRAM0`` covers HDEEM's DDR_AB +
DDR_CD and ``DRAM1`` covers DDR_EF + DDR_GH (:data:`~hdeem_watch.sources.base.RAPL_DRAM_COVERS`);
consumers that want HDEEM's channels must sum pairs, never split a socket.

Each poll reads ``energy_uj`` and publishes one sample per zone, ``ΔE/Δt`` over the interval since
the previous read (so ``rate_hz`` is the poll rate, ``1/interval_s``). The counter wraps at
``max_energy_range_uj``: the delta is taken modulo ``range + 1``. A delta that cannot be trusted —
zero (the counter did not move: no new reading), or a power above ``max_power_w`` (several wraps or a
counter reset between polls) — is dropped, never published as a zero or a negative.

``energy_uj`` has been readable by root only since Linux 5.10 (the PLATYPUS side channel,
CVE-2020-8694): a permission error becomes :class:`SourceUnavailable` with the fix.
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hdeem_watch.sources.base import STATUS_OK, STATUS_STALE, ChannelInfo, SourceBatch, SourceUnavailable

DEFAULT_ROOT = "/sys/class/powercap"
PERMISSION_FIX = ("energy_uj is root-only since Linux 5.10 (CVE-2020-8694); run the daemon as the privileged "
                  "collector (root, e.g. the hdeem-watchd systemd unit), or grant read access to the dram "
                  "zones' energy_uj with a udev rule / systemd-tmpfiles 'z' line for the collector's group")

_ZONE_ID = re.compile(r"^intel-rapl(?:-mmio)?:(\d+)(?::(\d+))?$")


@dataclass(frozen=True)
class DramZone:
    """One DRAM zone: its channel name, directory, socket and counter range (µJ)."""

    channel: str
    path: Path
    socket: int
    max_energy_range_uj: int


def _read_text(path: Path) -> str:
    return path.read_text()


def find_dram_zones(root: str | Path = DEFAULT_ROOT,
                    read_text: Callable[[Path], str] = _read_text) -> list[DramZone]:
    """DRAM zones under ``root`` (flat ``intel-rapl:N:M`` entries as in sysfs, or nested), by socket.

    Raises:
        SourceUnavailable: ``root`` is missing, or holds no zone named ``dram``.
    """
    base = Path(root)
    if not base.is_dir():
        raise SourceUnavailable(f"rapl: {base} does not exist (no powercap: not Linux, or the intel_rapl "
                                "modules are not loaded)")
    candidates = sorted({p.resolve(): p for p in [*base.glob("intel-rapl*"), *base.glob("intel-rapl*/intel-rapl*")]
                         if p.is_dir()}.values(), key=lambda p: p.name)
    zones: dict[int, DramZone] = {}
    for zone in candidates:
        try:
            name = read_text(zone / "name").strip()
        except OSError:
            continue
        if name != "dram":
            continue
        m = _ZONE_ID.match(zone.name)
        socket = int(m.group(1)) if m else len(zones)
        try:
            rng = int(read_text(zone / "max_energy_range_uj").strip())
        except PermissionError:
            raise SourceUnavailable(f"rapl: permission denied reading {zone / 'max_energy_range_uj'}; "
                                    f"{PERMISSION_FIX}") from None
        except (OSError, ValueError):
            continue
        if socket not in zones:
            zones[socket] = DramZone(f"DRAM{socket}", zone, socket, rng)
    if not zones:
        raise SourceUnavailable(f"rapl: no DRAM zone (a powercap zone named 'dram') under {base}: this CPU or "
                                "BIOS does not expose RAPL DRAM energy (client CPUs never do)")
    return [zones[s] for s in sorted(zones)]


def probe(root: str | Path | None = None) -> str | None:
    """``None`` if a RAPL DRAM source can be opened here, else why not (with the fix)."""
    try:
        for zone in find_dram_zones(root or DEFAULT_ROOT):
            (zone.path / "energy_uj").read_text()
    except SourceUnavailable as exc:
        return exc.reason
    except PermissionError:
        return f"rapl: permission denied reading energy_uj; {PERMISSION_FIX}"
    except OSError as exc:
        return f"rapl: cannot read energy_uj: {exc}"
    return None


def wrap_delta_uj(previous: int, current: int, max_range_uj: int) -> int:
    """Counter delta across at most one wrap: ``(current − previous) mod (range + 1)``.

    >>> wrap_delta_uj(100, 250, 1000)
    150
    >>> wrap_delta_uj(990, 40, 1000)
    51
    """
    return (current - previous) % (max_range_uj + 1)


class RaplSource:
    """Per-socket DRAM power from powercap.

    Args:
        root: the powercap directory (``/sys/class/powercap``; tests pass a fixture tree).
        interval_s: the counters are read at most this often (polls in between return no samples);
            the nominal ``rate_hz`` is ``1/interval_s``.
        max_power_w: a delta implying more than this per socket is dropped (multiple wraps / reset).
        clock: monotonic clock (ns); Δt is measured on it.
        wall_clock: wall clock (ns) for sample timestamps.
        read_text: file reader (injectable, e.g. to simulate EACCES when tests run as root).

    Example:
        >>> src = RaplSource(root="/nonexistent")
        >>> src.open()
        Traceback (most recent call last):
        ...
        hdeem_watch.sources.base.SourceUnavailable: rapl: /nonexistent does not exist (no powercap: not Linux, or the intel_rapl modules are not loaded)
    """

    kind = "rapl"

    def __init__(self, root: str | Path = DEFAULT_ROOT, *, method: str = "powercap", interval_s: float = 0.1,
                 max_power_w: float = 500.0,
                 clock: Callable[[], int] = time.monotonic_ns, wall_clock: Callable[[], int] = time.time_ns,
                 read_text: Callable[[Path], str] = _read_text) -> None:
        self.root = Path(root)
        self.method = method
        self.interval_s = interval_s
        self.interval_ns = int(interval_s * 1e9)
        #: samples/s of the ΔE/Δt channels (10 when polled without a limit)
        self.nominal_rate_hz = 1.0 / interval_s if interval_s > 0 else 10.0
        self._last_poll_ns: int | None = None
        self._last_status: dict[str, str] = {}
        self.max_power_w = max_power_w
        self._clock, self._wall, self._read = clock, wall_clock, read_text
        self.zones: list[DramZone] = []
        self._last: dict[str, tuple[int, int]] = {}   # channel -> (energy_uj, t_mono_ns)
        self._energy_j: dict[str, float] = {}
        self._health = "closed"
        self.dropped: dict[str, int] = {}

    def channels(self) -> list[ChannelInfo]:
        """``DRAM<socket>`` per DRAM zone (after :meth:`open`)."""
        return [ChannelInfo(z.channel, self.nominal_rate_hz, "dram") for z in self.zones]

    def _energy_uj(self, zone: DramZone) -> int:
        try:
            return int(self._read(zone.path / "energy_uj").strip())
        except PermissionError:
            raise SourceUnavailable(f"rapl: permission denied reading {zone.path / 'energy_uj'}; "
                                    f"{PERMISSION_FIX}") from None

    def open(self) -> None:
        """Find the DRAM zones and take the first reading.

        Raises:
            SourceUnavailable: no powercap, no DRAM zone, or permission denied (with the fix).
        """
        self.zones = find_dram_zones(self.root, self._read)
        now = int(self._clock())
        self._last = {z.channel: (self._energy_uj(z), now) for z in self.zones}
        self._energy_j = {z.channel: 0.0 for z in self.zones}
        self.dropped = {z.channel: 0 for z in self.zones}
        self._health = "ok"

    def close(self) -> None:
        """Nothing to release (idempotent)."""
        self._health = "closed"

    def health(self) -> str:
        """``"ok"``, ``"closed"`` or the last read error."""
        return self._health

    def poll(self) -> SourceBatch:
        """One ``ΔE/Δt`` sample per zone whose counter moved; untrustworthy deltas dropped."""
        now = int(self._clock())
        wall = int(self._wall())
        samples: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        status: dict[str, str] = {}
        if self._last_poll_ns is not None and now - self._last_poll_ns < self.interval_ns:
            nothing = {z.channel: (np.zeros(0, dtype=np.int64), np.zeros(0)) for z in self.zones}
            return SourceBatch(now, wall, nothing, dict(self._energy_j), dict(self._last_status))
        self._last_poll_ns = now
        for zone in self.zones:
            ch = zone.channel
            empty = (np.zeros(0, dtype=np.int64), np.zeros(0))
            try:
                current = self._energy_uj(zone)
            except (OSError, ValueError) as exc:
                samples[ch], status[ch] = (np.array([wall], dtype=np.int64), np.array([math.nan])), f"error: {exc}"
                self._health = f"error: {ch}: {exc}"
                continue
            previous, t_prev = self._last[ch]
            dt_s = (now - t_prev) * 1e-9
            if current == previous or dt_s <= 0:
                samples[ch], status[ch] = empty, STATUS_STALE   # no new reading: keep the old baseline
                continue
            delta = wrap_delta_uj(previous, current, zone.max_energy_range_uj)
            self._last[ch] = (current, now)
            power = delta * 1e-6 / dt_s
            if power > self.max_power_w:
                self.dropped[ch] += 1                           # cannot be corrected: drop, re-baseline
                samples[ch], status[ch] = empty, "error: implausible counter jump (dropped)"
                continue
            self._energy_j[ch] += delta * 1e-6
            samples[ch] = (np.array([wall], dtype=np.int64), np.array([power]))
            status[ch] = STATUS_OK
        self._last_status = status
        return SourceBatch(now, wall, samples, dict(self._energy_j), status)
