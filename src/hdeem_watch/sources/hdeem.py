"""HDEEM source: libhdeem through the C shim, used the way HDEEM's own tools use it.

**Passive by default.** The HDEEM measurement (``hdeem_start``/``hdeem_stop``/``hdeem_clear``) belongs
to the node's users: Score-P's HDEEM plugin, phdeem and job scripts start and stop it, and a
monitor that cleared or stopped it would destroy their data. So, like MetricQ's HDEEM source
(``tud-zih-energy/metricq-source-hdeem``, which only ever calls ``get_stats_total``), this source
never calls start, clear or stop unless ``own_measurement=True``. Owning the measurement means: it
is (re)started at open, stopped at close, and re-armed (stop, clear, start) every ``rearm_s``, well
before the BMC's 8-hour buffer overflows — and any other tool's measurement on the node is
destroyed each time.

Two methods:

* ``"energy"`` (default): every poll reads the energy totals since power-on
  (``hdeem_get_stats_total``; "no call to hdeem_start() or hdeem_stop() is needed", hdeem_cxx) and
  publishes, per sensor, one sample ``ΔE/Δt`` over the interval between the BMC's read times,
  stamped at the read time. No energy is lost between polls: after a missed or failed poll the next
  good one covers the whole interval. ``rate_hz`` of every channel is the poll rate
  (``1/interval_s``). Works whether or not a measurement runs; if none does, :meth:`health` says so.
* ``"global"``: every poll reads the sample buffer of the running measurement
  (``hdeem_get_global``) and publishes the new samples at the measured rates, stamped from the
  measurement's ``start_time_blade`` with periods measured as duration ÷ count and VR samples
  shifted by Score-P's −29.4 ms (:mod:`hdeem_watch.sources.hdeem_timing`). Passive, it needs a
  measurement somebody else started; owning, it re-arms every ``rearm_s`` (600 s) to keep reads short.

Quirks: ``hdeem_start`` fails while a measurement runs (clear, then start again); ``hdeem_stop`` is
asynchronous (poll the status until neither BMC nor FPGA polls, then read the overflow flags);
``get_stats`` latency is irregular (a call slower than ``slow_s`` counts as missing data: NaN and
status ``"stale"``, and the next good poll covers the interval); connections fail (NaN samples with
``"error: ..."``, reconnect with exponential back-off ``backoff_s`` doubling up to ``backoff_max_s``);
sensor names vary in case and ``_``/space (normalised onto :data:`~hdeem_watch.sources.base.CHANNELS`).
"""

from __future__ import annotations

import contextlib
import math
import os
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from hdeem_watch.sources.base import (
    STATUS_GAP,
    STATUS_OK,
    STATUS_OVERFLOW,
    STATUS_STALE,
    ChannelInfo,
    ChannelKind,
    QuietLimit,
    SourceBatch,
    SourceUnavailable,
    normalise_channel_name,
)
from hdeem_watch.sources.hdeem_global import GlobalReader
from hdeem_watch.sources.hdeem_lib import (
    BLADE_OVERFLOW,
    BMC_OVERFLOW,
    BMC_POLLING,
    DEFAULT_LIB_NAMES,
    DEFAULT_LIBS,
    FEATURE_GLOBAL,
    FEATURE_STATUS_TIMES,
    FPGA_POLLING,
    PERMISSION_CODES,
    VR_OVERFLOW,
    HdeemError,
    ShimLib,
    StatusReading,
    build_shim,
    find_compiler,
    find_header,
    find_library,
    shim_build_notes,
)

PERMISSION_FIX = ("run the daemon as the privileged collector (root, or the service user with access to "
                  "/dev/ipmi0 / the BMC credentials), e.g. the hdeem-watchd systemd unit")
#: The BMC keeps a measurement's samples for 8 hours; a measurement running longer overflows.
BMC_BUFFER_S = 8 * 3600.0
#: Re-arm period of an owned measurement, per method (both well inside :data:`BMC_BUFFER_S`).
DEFAULT_REARM_S = {"energy": 4 * 3600.0, "global": 600.0}
NO_MEASUREMENT = "no HDEEM measurement running"


def probe(include_dir: str | None = None, lib_dir: str | None = None,
          lib_names: Sequence[str] = DEFAULT_LIB_NAMES) -> str | None:
    """``None`` if an HDEEM source can be built here, else why not (without touching the BMC)."""
    if find_compiler() is None:
        return "hdeem: no C compiler (cc/gcc/clang) to build the libhdeem shim; install gcc"
    if find_header(include_dir) is None:
        return ("hdeem: hdeem.h not found (libhdeem is present only on Bull/Atos HDEEM nodes); set "
                "hdeem_include_dir (HDEEM_WATCH_HDEEM_INCLUDE_DIR, --hdeem-include-dir)")
    if find_library(lib_dir, lib_names) is None:
        return ("hdeem: libhdeem not found (present only on Bull/Atos HDEEM nodes); set hdeem_lib_dir "
                "(HDEEM_WATCH_HDEEM_LIB_DIR, --hdeem-lib-dir)")
    if os.path.exists("/dev/ipmi0") and not os.access("/dev/ipmi0", os.R_OK | os.W_OK):
        return f"hdeem: permission denied on /dev/ipmi0; {PERMISSION_FIX}"
    return None


class HdeemSource:
    """HDEEM through libhdeem.

    Args:
        host, user, password: BMC for out-of-band access (``None`` = in-band). The password is
            never logged nor shown in errors.
        include_dir, lib_dir, cache_dir, cc, libs, cflags, lib_names: how to build the shim (see
            ``build_shim``).
        method: ``"energy"`` or ``"global"``.
        own_measurement: start, re-arm and stop the HDEEM measurement (destroys other tools'
            measurements); default passive: never call ``hdeem_start``/``hdeem_clear``/``hdeem_stop``.
        interval_s: the BMC is read at most this often (polls in between return no samples); the
            nominal ``rate_hz`` of the ``"energy"`` method is ``1/interval_s``.
        slow_s: a ``get_stats`` call slower than this is missing data.
        backoff_s, backoff_max_s: reconnect back-off (doubling).
        stop_timeout_s: how long to wait for an asynchronous stop (public wrappers allow 10 s).
        status_every_s: how often to read the status (flags, start time).
        rearm_s: owning mode: re-arm the measurement after this long (default per method,
            :data:`DEFAULT_REARM_S`; must stay below the BMC's 8-hour buffer).
        clock: monotonic clock (ns) for back-off, status and re-arm timing.
        wall_clock: wall clock (ns) for NaN samples' timestamps.
        sleep: ``time.sleep`` (injectable).

    Example (on an HDEEM node)::

        src = HdeemSource(method="energy")   # passive: reads totals since power-on
        src.open(); batch = src.poll(); src.close()
    """

    kind = "hdeem"

    def __init__(self, host: str | None = None, user: str | None = None, password: str | None = None, *,
                 include_dir: str | None = None, lib_dir: str | None = None, cache_dir: str | None = None,
                 cc: str | None = None, libs: Sequence[str] = DEFAULT_LIBS, cflags: Sequence[str] = (),
                 lib_names: Sequence[str] = DEFAULT_LIB_NAMES, method: str = "energy",
                 own_measurement: bool = False, interval_s: float = 0.1, slow_s: float = 0.25,
                 backoff_s: float = 0.5, backoff_max_s: float = 30.0, stop_timeout_s: float = 10.0,
                 status_every_s: float = 1.0, rearm_s: float | None = None,
                 clock: Callable[[], int] = time.monotonic_ns, wall_clock: Callable[[], int] = time.time_ns,
                 sleep: Callable[[float], Any] = time.sleep) -> None:
        from hdeem_watch.errors import InputError

        if method not in ("energy", "global"):
            raise InputError(f"hdeem: method = {method!r}; expected 'energy' or 'global'")
        rearm = DEFAULT_REARM_S[method] if rearm_s is None else float(rearm_s)
        if not 0 < rearm < BMC_BUFFER_S:
            raise InputError(f"hdeem: rearm_s = {rearm_s!r}; expected 0 < rearm_s < {BMC_BUFFER_S:.0f} "
                             "(the BMC's buffer holds 8 hours)")
        self._conn = (host, user, password)
        self._build = dict(include_dir=include_dir, lib_dir=lib_dir, cache_dir=cache_dir, cc=cc, libs=tuple(libs),
                           cflags=tuple(cflags), lib_names=tuple(lib_names))
        self.method = method
        self.own_measurement = bool(own_measurement)
        self.interval_s = interval_s
        self.interval_ns = int(interval_s * 1e9)
        #: samples/s of the ΔE/Δt channels (10 when polled without a limit)
        self.nominal_rate_hz = 1.0 / interval_s if interval_s > 0 else 10.0
        self._last_poll_ns: int | None = None
        self._last_status: dict[str, str] = {}
        self.slow_s = slow_s
        self.backoff_s = backoff_s
        self.backoff_max_s = backoff_max_s
        self.stop_timeout_s = stop_timeout_s
        self.status_every_ns = int(status_every_s * 1e9)
        self.rearm_ns = int(rearm * 1e9)
        self._clock, self._wall, self._sleep = clock, wall_clock, sleep
        self.lib: ShimLib | None = None
        self._handle: int | None = None
        self._names: list[str] = []
        self._nblade = 1
        self._error: str | None = None
        self._retry_at = 0
        self._delay = backoff_s
        self._last_status_ns = -(1 << 62)
        self._status = StatusReading(0, None, None)
        self.overflow_at_stop: int | None = None
        self._e0: np.ndarray | None = None
        self._e_last: np.ndarray | None = None
        self._read_last: list[int] = [0, 0]
        self._global: GlobalReader | None = None
        self._armed_at = 0
        self._energy_j: dict[str, float] = {}
        self.reconnects = 0
        self.rearms = 0

    # -- lifecycle -----------------------------------------------------------------------------------
    def channels(self) -> list[ChannelInfo]:
        """The sensors (normalised names); rates per method: the poll rate (energy), the measured
        rates once known, else the nominal 1000 / 100 Sa/s (global)."""
        names = self._names or ["BLADE", "CPU0", "CPU1", "DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH"]
        periods = self.periods_ns or (1e6, 1e7)
        infos = []
        for i, name in enumerate(names):
            kind: ChannelKind = "blade" if i < self._nblade else ("dram" if name.startswith("DDR") else "cpu")
            native = 1e9 / periods[0 if i < self._nblade else 1]
            infos.append(ChannelInfo(name, native if self.method == "global" else self.nominal_rate_hz, kind))
        return infos

    def open(self) -> None:
        """Build/load the shim and connect; start a measurement only when owning it.

        Raises:
            SourceUnavailable: the shim cannot be built/loaded (or lacks what the method needs),
                permission denied (with the fix), or the BMC does not answer.
        """
        if self.lib is None:
            self.lib = ShimLib(build_shim(**self._build))  # type: ignore[arg-type]
            needed = FEATURE_GLOBAL | FEATURE_STATUS_TIMES if self.method == "global" else 0
            if self.lib.features & needed != needed:
                notes = shim_build_notes(self.lib.path)
                self.lib = None
                raise SourceUnavailable("hdeem: method 'global' needs hdeem_get_global and the status times, "
                                        f"which do not build against this hdeem.h ({notes}); use "
                                        "hdeem_method = 'energy'")
        try:
            self._connect()
        except HdeemError as exc:
            if exc.code in PERMISSION_CODES:
                raise SourceUnavailable(f"hdeem: hdeem_init: permission denied (code {exc.code}); "
                                        f"{PERMISSION_FIX}") from None
            raise SourceUnavailable(f"hdeem: {exc.call} failed with code {exc.code} (BMC unreachable or "
                                    "HDEEM disabled in the BIOS?)") from None
        assert self._e_last is not None
        self._e0 = self._e_last.copy()
        self._energy_j = dict.fromkeys(self._names, 0.0)
        if self.method == "global" and self._status.start_ns:   # measured rates for channels() at once
            assert self._handle is not None
            with contextlib.suppress(HdeemError):
                self._reader().measure(self._handle, self._status.start_ns)

    def _connect(self) -> None:
        assert self.lib is not None
        self._handle = self.lib.open(*self._conn)
        self._nblade, _ = self.lib.sensor_count(self._handle)
        self._names = [normalise_channel_name(n) for n in self.lib.sensor_names(self._handle)]
        self._status = self.lib.status(self._handle)
        self._last_status_ns = int(self._clock())
        if self.own_measurement and not self._status.running:
            self._start()
        reading = self.lib.stats(self._handle, True, len(self._names))
        if self._e_last is None:  # on a reconnect keep the baseline: totals since power-on go on
            self._e_last = reading.energy_j.copy()
            self._read_last = list(reading.read_ns)
        self._error = None
        self._delay = self.backoff_s

    def _start(self) -> None:
        """Owning mode: ``hdeem_start``; it fails while a measurement runs, so clear and start again."""
        assert self.own_measurement and self.lib is not None and self._handle is not None
        if self.lib.start(self._handle) != 0:
            self.lib.clear(self._handle)
            rc = self.lib.start(self._handle)
            if rc != 0:
                raise HdeemError("hdeem_start", rc)
        self._armed_at = int(self._clock())
        self._status = self.lib.status(self._handle)

    def stop(self) -> int:
        """Owning mode: stop the measurement and wait until neither BMC nor FPGA polls; returns the
        overflow flags."""
        assert self.own_measurement, "a passive source never stops the HDEEM measurement"
        assert self.lib is not None and self._handle is not None
        self.lib.stop(self._handle)
        deadline = time.monotonic() + self.stop_timeout_s
        flags = self.lib.status(self._handle).flags
        while flags & (BMC_POLLING | FPGA_POLLING) and time.monotonic() < deadline:
            self._sleep(0.005)
            flags = self.lib.status(self._handle).flags
        self.overflow_at_stop = flags & (BMC_OVERFLOW | BLADE_OVERFLOW | VR_OVERFLOW)
        return self.overflow_at_stop

    def close(self) -> None:
        """Disconnect (idempotent); when owning the measurement, stop it first (waiting for the
        asynchronous stop) and read the overflow flags."""
        if self.lib is None or self._handle is None:
            return
        if self.own_measurement:
            with contextlib.suppress(HdeemError):
                self.stop()
        self.lib.close(self._handle)
        self._handle = None

    @property
    def quiet_limit(self) -> QuietLimit:
        """The BMC keeps a measurement's samples 8 hours (an owned one must be re-armed before);
        the energy method publishes one ΔE/Δt sample per read (paced)."""
        limit = BMC_BUFFER_S - self.rearm_ns / 1e9 if self.own_measurement else BMC_BUFFER_S
        return QuietLimit(limit, paced=self.method == "energy")

    def health(self) -> str:
        """``"ok"``, the connection error, the overflow flags, or that no measurement runs."""
        if self._handle is None and self._error is None:
            return "closed"
        if self._error:
            return f"error: {self._error}"
        flags = self._status.flags
        if flags & (BMC_OVERFLOW | BLADE_OVERFLOW | VR_OVERFLOW):
            return f"overflow (flags 0x{flags:02x})"
        if not self._status.running:
            if self.method == "global":
                return (f"idle: {NO_MEASUREMENT}; the global method reads a running measurement's buffer "
                        "(start one, e.g. with Score-P's HDEEM plugin, or set hdeem_own_measurement = true)")
            return f"ok; {NO_MEASUREMENT} (the totals since power-on need none)"
        return "ok"

    # -- polling ---------------------------------------------------------------------------------------
    def poll(self) -> SourceBatch:
        """New samples (see the module docstring); NaN samples with a status when the BMC fails."""
        if self.lib is None:
            raise RuntimeError("HdeemSource.poll() before open()")
        now = int(self._clock())
        if self._last_poll_ns is not None and now - self._last_poll_ns < self.interval_ns:
            return self._empty_batch(now)   # the BMC is read at most every interval_s
        self._last_poll_ns = now
        batch = self._poll_now(now)
        self._last_status = dict(batch.status)
        return batch

    def _empty_batch(self, now: int) -> SourceBatch:
        empty = {n: (np.zeros(0, dtype=np.int64), np.zeros(0)) for n in self._names}
        energy = dict(self._energy_j) if self._error is None else {n: math.nan for n in self._names}
        status = self._last_status or dict.fromkeys(self._names, STATUS_OK)
        return SourceBatch(now, int(self._wall()), empty, energy, dict(status))

    def _poll_now(self, now: int) -> SourceBatch:
        if self._handle is None:
            if now < self._retry_at:
                return self._failed_batch(now, f"error: {self._error}; retry in {(self._retry_at - now) / 1e9:.1f} s")
            try:
                self.reconnects += 1
                self._connect()
            except HdeemError as exc:
                return self._lost(now, exc)
        try:
            self._check_status(now)
            if self.own_measurement and self.method == "energy" and now - self._armed_at >= self.rearm_ns:
                self._rearm()
            if self.method == "global":
                return self._poll_global(now)
            return self._poll_energy(now)
        except HdeemError as exc:
            return self._lost(now, exc)

    def _lost(self, now: int, exc: HdeemError) -> SourceBatch:
        """Connection failure: drop the handle, schedule a reconnect with exponential back-off."""
        assert self.lib is not None
        if self._handle is not None:
            with contextlib.suppress(Exception):  # the connection is already broken
                self.lib.close(self._handle)
            self._handle = None
        self._error = f"{exc.call} failed (code {exc.code})"
        self._retry_at = now + int(self._delay * 1e9)
        self._delay = min(self._delay * 2, self.backoff_max_s)
        return self._failed_batch(now, f"error: {self._error}")

    def _failed_batch(self, now: int, status: str) -> SourceBatch:
        wall = int(self._wall())
        nan = {n: (np.array([wall], dtype=np.int64), np.array([math.nan])) for n in self._names}
        return SourceBatch(now, wall, nan, {n: math.nan for n in self._names}, dict.fromkeys(self._names, status))

    def _check_status(self, now: int) -> None:
        assert self.lib is not None and self._handle is not None
        if now - self._last_status_ns >= self.status_every_ns:
            self._status = self.lib.status(self._handle)
            self._last_status_ns = now

    def _rearm(self) -> None:
        """Owning mode: stop (waiting), clear and start again, before the BMC's buffer overflows."""
        assert self.lib is not None and self._handle is not None
        self.stop()
        self.lib.clear(self._handle)
        self._start()
        self.rearms += 1

    def _group_status(self, i: int) -> str:
        bits = BLADE_OVERFLOW if i < self._nblade else VR_OVERFLOW
        return STATUS_OVERFLOW if self._status.flags & (bits | BMC_OVERFLOW) else STATUS_OK

    def _poll_energy(self, now: int) -> SourceBatch:
        assert self.lib is not None and self._handle is not None
        assert self._e_last is not None and self._e0 is not None
        t0 = time.perf_counter()
        reading = self.lib.stats(self._handle, True, len(self._names))
        slow = time.perf_counter() - t0 > self.slow_s
        wall = int(self._wall())
        samples: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        status: dict[str, str] = {}
        for i, name in enumerate(self._names):
            g = 0 if i < self._nblade else 1
            if slow:
                samples[name] = (np.array([wall], dtype=np.int64), np.array([math.nan]))
                status[name] = STATUS_STALE
                continue
            t_read, t_last = reading.read_ns[g], self._read_last[g]
            de = float(reading.energy_j[i] - self._e_last[i])
            if t_read <= t_last:
                samples[name] = (np.zeros(0, dtype=np.int64), np.zeros(0))
                status[name] = self._group_status(i)
            elif de < 0:  # the counter went backwards (BMC reset): restart the baseline
                samples[name] = (np.array([t_read], dtype=np.int64), np.array([math.nan]))
                status[name] = "error: energy counter reset"
                self._e0[i] -= self._e_last[i] - reading.energy_j[i]
            else:
                samples[name] = (np.array([t_read], dtype=np.int64), np.array([de / ((t_read - t_last) * 1e-9)]))
                status[name] = self._group_status(i)
        if not slow:
            self._e_last = reading.energy_j.copy()
            self._read_last = [max(a, b) for a, b in zip(reading.read_ns, self._read_last)]
            self._energy_j = {n: float(self._e_last[i] - self._e0[i]) for i, n in enumerate(self._names)}
        return SourceBatch(now, wall, samples, dict(self._energy_j), status)

    @property
    def periods_ns(self) -> tuple[float, float] | None:
        """Global method: the measured sampling periods (blade, VR) in ns, once known."""
        return self._global.periods_ns if self._global is not None else None

    def _reader(self) -> GlobalReader:
        assert self.lib is not None
        if self._global is None or self._global.names != self._names:
            self._global = GlobalReader(self.lib, self._names, self._nblade)
        return self._global

    def _poll_global(self, now: int) -> SourceBatch:
        assert self.lib is not None and self._handle is not None
        if not self._status.running and self._status.start_ns in (None, 0):
            empty = {n: (np.zeros(0, dtype=np.int64), np.zeros(0)) for n in self._names}
            return SourceBatch(now, int(self._wall()), empty, dict(self._energy_j),
                               dict.fromkeys(self._names, STATUS_STALE))
        reader = self._reader()
        samples, gaps = reader.collect(self._handle, self._energy_j)
        if self.own_measurement and now - self._armed_at >= self.rearm_ns:  # take what is left, re-arm
            self.stop()
            rest, rest_gaps = reader.collect(self._handle, self._energy_j)
            samples = {n: (np.concatenate([samples[n][0], rest[n][0]]), np.concatenate([samples[n][1], rest[n][1]]))
                       for n in samples}
            t_stop = int(self._clock())
            self.lib.clear(self._handle)
            self._start()
            self.rearms += 1
            lost_s = (int(self._clock()) - t_stop) * 1e-9
            periods = reader.periods_ns or (1e6, 1e7)
            gaps = {n: gaps.get(n, 0) + rest_gaps.get(n, 0)
                    + max(1, round(lost_s * 1e9 / periods[0 if i < self._nblade else 1]))
                    for i, n in enumerate(self._names)}
        status = {n: STATUS_GAP if gaps.get(n) else self._group_status(i) for i, n in enumerate(self._names)}
        return SourceBatch(now, int(self._wall()), samples, dict(self._energy_j), status, gaps)
