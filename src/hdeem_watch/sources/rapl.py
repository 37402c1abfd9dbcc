"""RAPL DRAM source: per-socket DRAM energy counters, read through powercap or the perf ``power`` PMU.

RAPL reports DRAM energy **per socket** (per die on multi-die packages), not per DIMM pair. Channels
are named by socket from the package zone's name (:mod:`hdeem_watch.sources.rapl_zones`): ``DRAM<X>``
or ``DRAM<X>_DIE<Y>``, for any number of sockets. On the modelled Haswell-EP node ``DRAM0`` covers
HDEEM's DDR_AB + DDR_CD and ``DRAM1`` covers DDR_EF + DDR_GH
(:data:`~hdeem_watch.sources.base.RAPL_DRAM_COVERS`); never split a socket.

Two ways to the same counters (``method``): ``"powercap"`` reads ``energy_uj`` of the ``dram`` zones
(root-only since the CVE-2020-8694 fix unless the udev rule opens them); ``"perf"`` opens the
``power/energy-ram`` event once per socket with ``perf_event_open``
(:mod:`hdeem_watch.sources.perf_energy`; needs ``perf_event_paranoid`` <= 0 or ``CAP_PERFMON``);
``"auto"`` tries powercap, then perf.

Each read publishes one sample per counter, ``ΔE/Δt`` over the interval since the previous read
(``rate_hz`` = the read rate, ``1/interval_s``; a read is due once 90 % of the interval has passed, so
a poll a little early does not skip a whole interval). powercap counters wrap after
``max_energy_range_uj`` plus one counter unit (the 32-bit register's period,
:func:`~hdeem_watch.sources.rapl_zones.wrap_modulus_uj`); perf counts are 64-bit. A delta that cannot be
trusted — zero (no new reading), negative, or above ``max_power_w`` (several wraps or a reset) — is
dropped, never published as a zero or a negative. :meth:`RaplSource.health` is the state of the last
read: an error clears once every counter reads again.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from hdeem_watch.sources.base import (
    STATUS_OK,
    STATUS_STALE,
    ChannelInfo,
    QuietLimit,
    SourceBatch,
    SourceUnavailable,
)
from hdeem_watch.sources.rapl_zones import (
    DEFAULT_ROOT,
    PERMISSION_FIX,
    DramZone,
    EnergyCounter,
    find_dram_zones,
    read_text,
    wrap_delta_uj,
    wrap_modulus_uj,
)

__all__ = ["DEFAULT_ROOT", "PERMISSION_FIX", "EnergyCounter", "RaplSource", "probe", "wrap_delta_uj",
           "wrap_modulus_uj"]

METHODS = ("auto", "powercap", "perf")
#: A read is due once this fraction of ``interval_s`` has passed since the previous one.
DUE_FRACTION = 0.9


def powercap_counters(root: str | Path, read: Callable[[Path], str] = read_text,
                      cpuinfo: str | Path = "/proc/cpuinfo") -> list[EnergyCounter]:
    """The DRAM zones as counters (µJ, with the period 2³² units = ``max_energy_range_uj`` + one unit)."""

    def reader(zone: DramZone) -> Callable[[], int]:
        return lambda: int(read(zone.path / "energy_uj").strip())

    return [EnergyCounter(z.channel, reader(z), 1e-6, wrap_modulus_uj(z.max_energy_range_uj))
            for z in find_dram_zones(root, read, cpuinfo)]


def probe(root: str | Path | None = None) -> str | None:
    """``None`` if a RAPL DRAM source can be opened here through powercap, else why not (with the fix)."""
    try:
        for counter in powercap_counters(root or DEFAULT_ROOT):
            counter.read_raw()
    except SourceUnavailable as exc:
        return exc.reason
    except PermissionError:
        return f"rapl: permission denied reading energy_uj; {PERMISSION_FIX}"
    except (OSError, ValueError) as exc:
        return f"rapl: cannot read energy_uj: {exc}"
    return None


class RaplSource:
    """Per-socket DRAM power from RAPL.

    Args:
        root: the powercap directory (``/sys/class/powercap``; tests pass a fixture tree).
        method: ``"powercap"``, ``"perf"`` or ``"auto"`` (powercap, else perf).
        interval_s: the counters are read at most this often (polls in between return no samples);
            the nominal ``rate_hz`` is ``1/interval_s``.
        max_power_w: a delta implying more than this per counter is dropped (multiple wraps / reset).
        clock: monotonic clock (ns); Δt is measured on it.
        wall_clock: wall clock (ns) for sample timestamps.
        read_text: sysfs reader (injectable, e.g. to simulate EACCES when tests run as root).
        cpuinfo: ``/proc/cpuinfo`` (for the reason when there is no DRAM zone).
        perf_options: options of :func:`hdeem_watch.sources.perf_energy.perf_counters` (``sysfs``,
            ``opener``...).

    Example:
        >>> src = RaplSource(root="/nonexistent", method="powercap")
        >>> src.open()
        Traceback (most recent call last):
        ...
        hdeem_watch.sources.base.SourceUnavailable: rapl: /nonexistent does not exist (no powercap: not Linux, or the intel_rapl modules are not loaded)
    """

    kind = "rapl"

    def __init__(self, root: str | Path = DEFAULT_ROOT, *, method: str = "powercap", interval_s: float = 0.1,
                 max_power_w: float = 500.0, clock: Callable[[], int] = time.monotonic_ns,
                 wall_clock: Callable[[], int] = time.time_ns, read_text: Callable[[Path], str] = read_text,
                 cpuinfo: str | Path = "/proc/cpuinfo", perf_options: dict | None = None) -> None:
        from hdeem_watch.errors import InputError

        if method not in METHODS:
            raise InputError(f"rapl: method = {method!r}; expected one of {', '.join(METHODS)}")
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
        self._cpuinfo = cpuinfo
        self._perf_options = dict(perf_options or {})
        self.counters: list[EnergyCounter] = []
        self.used_method: str | None = None
        self._close_perf: Callable[[], None] | None = None
        self._last: dict[str, tuple[int, int]] = {}   # channel -> (raw count, t_mono_ns)
        self._energy_j: dict[str, float] = {}
        self._health = "closed"
        self.dropped: dict[str, int] = {}

    def channels(self) -> list[ChannelInfo]:
        """One DRAM channel per counter (after :meth:`open`)."""
        return [ChannelInfo(c.channel, self.nominal_rate_hz, "dram") for c in self.counters]

    def _first_read(self, counter: EnergyCounter) -> int:
        try:
            return counter.read_raw()
        except PermissionError as exc:
            raise SourceUnavailable(f"rapl: permission denied reading {exc.filename or counter.channel}; "
                                    f"{PERMISSION_FIX}") from None

    def _open_powercap(self) -> None:
        counters = powercap_counters(self.root, self._read, self._cpuinfo)
        self._last = {}
        now = int(self._clock())
        for counter in counters:
            self._last[counter.channel] = (self._first_read(counter), now)
        self.counters, self.used_method = counters, "powercap"

    def _open_perf(self) -> None:
        from hdeem_watch.sources.perf_energy import perf_counters

        counters, close = perf_counters(**self._perf_options)
        now = int(self._clock())
        self._last = {c.channel: (c.read_raw(), now) for c in counters}
        self.counters, self.used_method, self._close_perf = counters, "perf", close

    def open(self) -> None:
        """Find the counters (by ``method``) and take the first reading.

        Raises:
            SourceUnavailable: no powercap / no DRAM zone / permission denied, and (perf, auto) no
                usable power PMU; the reason says why each way failed and the fix.
        """
        if self.method == "perf":
            self._open_perf()
        elif self.method == "powercap":
            self._open_powercap()
        else:
            try:
                self._open_powercap()
            except SourceUnavailable as powercap:
                try:
                    self._open_perf()
                except SourceUnavailable as perf:
                    raise SourceUnavailable(f"{powercap.reason}; and through perf: {perf.reason}") from None
        self._energy_j = {c.channel: 0.0 for c in self.counters}
        self.dropped = {c.channel: 0 for c in self.counters}
        self._health = "ok"

    def close(self) -> None:
        """Release perf events (idempotent)."""
        if self._close_perf is not None:
            self._close_perf()
            self._close_perf = None
        self._health = "closed"

    @property
    def quiet_limit(self) -> QuietLimit:
        """One ΔE/Δt sample per read (paced); a read must come before a counter can wrap twice: its
        range at ``max_power_w`` (a DRAM zone's 2³² × 15.3 µJ ≈ 65 kJ: 131 s at 500 W; perf counts do
        not wrap)."""
        wraps = [c.modulus * c.joules_per_unit / self.max_power_w for c in self.counters if c.modulus]
        return QuietLimit(min(wraps, default=math.inf), paced=True)

    def health(self) -> str:
        """``"ok"``, ``"closed"``, or the errors of the last read (cleared when every counter reads)."""
        return self._health

    def poll(self) -> SourceBatch:
        """One ``ΔE/Δt`` sample per counter that moved; untrustworthy deltas dropped."""
        now = int(self._clock())
        wall = int(self._wall())
        if self._last_poll_ns is not None and now - self._last_poll_ns < DUE_FRACTION * self.interval_ns:
            nothing = {c.channel: (np.zeros(0, dtype=np.int64), np.zeros(0)) for c in self.counters}
            return SourceBatch(now, wall, nothing, dict(self._energy_j), dict(self._last_status))
        self._last_poll_ns = now
        samples: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        status: dict[str, str] = {}
        errors = []
        empty = (np.zeros(0, dtype=np.int64), np.zeros(0))
        for counter in self.counters:
            ch = counter.channel
            try:
                current = counter.read_raw()
            except (OSError, ValueError) as exc:
                samples[ch], status[ch] = (np.array([wall], dtype=np.int64), np.array([math.nan])), f"error: {exc}"
                errors.append(f"{ch}: {exc}")
                continue
            previous, t_prev = self._last[ch]
            dt_s = (now - t_prev) * 1e-9
            if current == previous or dt_s <= 0:
                samples[ch], status[ch] = empty, STATUS_STALE   # no new reading: keep the old baseline
                continue
            delta = wrap_delta_uj(previous, current, counter.modulus) if counter.modulus else current - previous
            self._last[ch] = (current, now)
            energy = delta * counter.joules_per_unit
            power = energy / dt_s
            if delta < 0 or power > self.max_power_w:
                self.dropped[ch] += 1                           # cannot be corrected: drop, re-baseline
                samples[ch], status[ch] = empty, "error: implausible counter jump (dropped)"
                continue
            self._energy_j[ch] += energy
            samples[ch] = (np.array([wall], dtype=np.int64), np.array([power]))
            status[ch] = STATUS_OK
        self._health = f"error: {'; '.join(errors)}" if errors else "ok"
        self._last_status = status
        return SourceBatch(now, wall, samples, dict(self._energy_j), status)
