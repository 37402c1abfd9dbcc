"""Build and load the C shim over libhdeem (``hdeem_shim.c``) and call it through ctypes.

The shim is compiled at run time against the node's own ``hdeem.h`` (its layouts are not public),
``cc -shared -fPIC -O2 hdeem_shim.c -I<include> -L<lib> -Wl,-rpath,<lib> -lhdeem -lfreeipmi -lrt``,
into a cache directory keyed by the shim's source, the header's content and the link line, so a
node builds it once. Everything here is a thin typed wrapper; policy (quirks, retries) lives in
:mod:`hdeem_watch.sources.hdeem`.

Example (on a node with HDEEM)::

    lib = ShimLib(build_shim())
    handle = lib.open()
    names = lib.sensor_names(handle)
"""

from __future__ import annotations

import ctypes
import ctypes.util
import hashlib
import os
import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hdeem_watch.sources.base import SourceUnavailable

SHIM_SOURCE = Path(__file__).with_name("hdeem_shim.c")
DEFAULT_INCLUDE_DIRS = ("/usr/include", "/usr/local/include", "/opt/hdeem/include", "/usr/include/hdeem")
DEFAULT_LIBS = ("hdeem", "freeipmi", "rt")
#: File names libhdeem is looked up by in ``lib_dir`` (sites install ``libhdeem.so.1``, e.g.
#: ``/usr/local/hdeem/libhdeem.so.1`` in Score-P's HDEEM plugin README).
DEFAULT_LIB_NAMES = ("libhdeem.so", "libhdeem.so.1", "libhdeem.a")
#: Feature bits of :meth:`ShimLib.features`: which optional function sets of the shim were built.
FEATURE_STATUS_TIMES, FEATURE_GLOBAL = 0x01, 0x02
#: Optional function sets, as the macros that leave them out (tried in this order when a set fails).
_OPTIONAL_SETS = ((), ("-DHWS_NO_GLOBAL",), ("-DHWS_NO_STATUS_TIMES",), ("-DHWS_NO_GLOBAL", "-DHWS_NO_STATUS_TIMES"))

#: Status flags returned by :meth:`ShimLib.status` (the shim maps hdeem.h's macros onto them).
BMC_POLLING, FPGA_POLLING, BMC_OVERFLOW, BLADE_OVERFLOW, VR_OVERFLOW = 0x01, 0x02, 0x04, 0x08, 0x10
#: Codes meaning "permission denied" (negative errno EACCES/EPERM as HDEEM and freeipmi report them).
PERMISSION_CODES = (-13, 13)


class HdeemError(RuntimeError):
    """A libhdeem call returned a non-zero code."""

    def __init__(self, call: str, code: int) -> None:
        super().__init__(f"{call} returned {code}")
        self.call = call
        self.code = code


@dataclass(frozen=True)
class StatsReading:
    """One ``hdeem_get_stats``/``hdeem_get_stats_total`` result, sensors in library order.

    Attributes:
        energy_j, average_w, max_w, min_w, instant_w: per sensor.
        counts: samples (blade, vr).
        read_ns: wall-clock read times (blade, vr).
    """

    energy_j: np.ndarray
    average_w: np.ndarray
    max_w: np.ndarray
    min_w: np.ndarray
    instant_w: np.ndarray
    counts: tuple[int, int]
    read_ns: tuple[int, int]


def cache_root() -> Path:
    """Where the shim is built: ``$CACHE_DIRECTORY`` (systemd ``CacheDirectory=``), else
    ``$XDG_CACHE_HOME/hdeem-watch``, else ``~/.cache/hdeem-watch``."""
    if os.environ.get("CACHE_DIRECTORY"):
        return Path(os.environ["CACHE_DIRECTORY"].split(":")[0])
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "hdeem-watch"


def find_header(include_dir: str | os.PathLike[str] | None = None) -> Path | None:
    """The ``hdeem.h`` to compile against: in ``include_dir`` if given, else the usual places."""
    dirs = [Path(include_dir)] if include_dir else [Path(d) for d in DEFAULT_INCLUDE_DIRS]
    for d in dirs:
        if (d / "hdeem.h").is_file():
            return d / "hdeem.h"
    return None


def find_library(lib_dir: str | os.PathLike[str] | None = None,
                 names: Sequence[str] = DEFAULT_LIB_NAMES) -> str | None:
    """Path (or soname) of libhdeem: the first of ``names`` in ``lib_dir`` if given, else the
    linker's search path."""
    if lib_dir:
        for name in names:
            if (Path(lib_dir) / name).exists():
                return str(Path(lib_dir) / name)
        return None
    return ctypes.util.find_library("hdeem")


def _link_args(lib_dir: str | os.PathLike[str] | None, libs: Sequence[str], lib_names: Sequence[str]) -> list[str]:
    """The linker options: ``-lhdeem`` where ``libhdeem.so`` exists, else ``-l:<file>`` (e.g. a site
    that installs only ``libhdeem.so.1``, without the development symlink)."""
    link = [f"-L{lib_dir}", f"-Wl,-rpath,{lib_dir}"] if lib_dir else []
    found = find_library(lib_dir, lib_names) if lib_dir else None
    for lib in libs:
        if lib == "hdeem" and found and Path(found).name not in ("libhdeem.so", "libhdeem.a"):
            link.append(f"-l:{Path(found).name}")
        else:
            link.append(f"-l{lib}")
    return link


def find_compiler(cc: str | None = None) -> str | None:
    """The C compiler to use: ``cc``, ``$CC``, then ``cc``/``gcc``/``clang`` on PATH."""
    for candidate in (cc, os.environ.get("CC"), "cc", "gcc", "clang"):
        if candidate and shutil.which(candidate):
            return candidate
    return None


def build_shim(include_dir: str | os.PathLike[str] | None = None, lib_dir: str | os.PathLike[str] | None = None,
               cache_dir: str | os.PathLike[str] | None = None, cc: str | None = None,
               libs: Sequence[str] = DEFAULT_LIBS, cflags: Sequence[str] = (),
               lib_names: Sequence[str] = DEFAULT_LIB_NAMES) -> Path:
    """Compile the shim (once per header/link line) and return the path of the shared object.

    The shim is built with all its function sets first; a set that does not compile against this
    ``hdeem.h`` (status times, global readings) is left out and the rest built again, so the energy
    path works wherever its own fields are as assumed. Which sets were built:
    :meth:`ShimLib.features`; why one was left out: :func:`shim_build_notes`.

    ``cflags`` adds compiler options, e.g. ``("-DHWS_NO_GPIO_FIELDS",)`` for a header whose
    ``hdeem_bmc_data_t`` has no ``hasGPIO``/``hasPCIe`` fields.

    Raises:
        SourceUnavailable: no compiler, no ``hdeem.h``, or even the core does not compile/link (the
            reason quotes the compiler).
    """
    compiler = find_compiler(cc)
    if compiler is None:
        raise SourceUnavailable("hdeem: no C compiler (cc/gcc/clang) to build the libhdeem shim; install gcc")
    header = find_header(include_dir)
    if header is None:
        where = include_dir or ", ".join(DEFAULT_INCLUDE_DIRS)
        raise SourceUnavailable(f"hdeem: hdeem.h not found in {where} (HDEEM is a Bull/Atos library present "
                                "only on HDEEM nodes); set hdeem_include_dir (HDEEM_WATCH_HDEEM_INCLUDE_DIR, "
                                "--hdeem-include-dir) to the directory of hdeem.h")
    source = SHIM_SOURCE.read_bytes()
    link = _link_args(lib_dir, libs, lib_names)
    flags = [str(f) for f in cflags]
    key = hashlib.sha256(source + header.read_bytes()
                         + repr((compiler, str(header), link, flags)).encode()).hexdigest()[:16]
    out_dir = Path(cache_dir) if cache_dir else cache_root()
    target = out_dir / f"shim-{key}" / "libhdeem_shim.so"
    if target.is_file():
        return target
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
    except OSError:  # e.g. no writable home under a hardened unit: fall back to a private temp dir
        target = Path(tempfile.gettempdir()) / f"hdeem-watch-{os.getuid()}" / f"shim-{key}" / "libhdeem_shim.so"
        if target.is_file():
            return target
        target.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
    notes: list[str] = []
    for dropped in _OPTIONAL_SETS:
        with tempfile.NamedTemporaryFile(dir=target.parent, suffix=".so", delete=False) as tmp:
            tmp_path = Path(tmp.name)
        cmd = [compiler, "-shared", "-fPIC", "-O2", "-Wall", *flags, *dropped, "-o", str(tmp_path),
               str(SHIM_SOURCE), f"-I{header.parent}", *link]
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if proc.returncode == 0:
            (target.parent / "build-notes.txt").write_text("\n".join(notes))
            tmp_path.replace(target)  # atomic: concurrent builders never see a half-written file
            return target
        tmp_path.unlink(missing_ok=True)
        errors = [line for line in proc.stderr.splitlines() if "error" in line] or proc.stderr.strip().splitlines()
        notes.append(f"{' '.join(dropped) or 'all sets'}: {' | '.join(errors[:3])}")
    raise SourceUnavailable(f"hdeem: building the shim failed ({' '.join(cmd)}): {notes[-1]}")


def shim_build_notes(path: str | os.PathLike[str]) -> str:
    """Why optional function sets were left out of the shim at ``path`` ('' if none were)."""
    notes = Path(path).with_name("build-notes.txt")
    return notes.read_text() if notes.is_file() else ""


_DP = ctypes.POINTER(ctypes.c_double)
_LLP = ctypes.POINTER(ctypes.c_longlong)


@dataclass(frozen=True)
class StatusReading:
    """``hdeem_check_status``: the flags (``BMC_POLLING`` ...) and the measurement's times.

    Attributes:
        flags: status bits of this module (the shim maps hdeem.h's ``Is...`` macros onto them).
        start_ns, stop_ns: ``start_time_blade`` / ``stop_time_blade`` as wall-clock ns (0 where the
            library reports none); ``None`` when the shim was built without the status-times set.
    """

    flags: int
    start_ns: int | None
    stop_ns: int | None

    @property
    def running(self) -> bool:
        """A measurement is running (the BMC or the FPGA polls)."""
        return bool(self.flags & (BMC_POLLING | FPGA_POLLING))


class ShimLib:
    """The loaded shim. Handles are opaque pointers returned by :meth:`open`."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        try:
            self._lib = ctypes.CDLL(str(path))
        except OSError as exc:
            raise SourceUnavailable(f"hdeem: cannot load the shim {path}: {exc}") from None
        self.path = Path(path)
        lib = self._lib
        lib.hws_open.restype = ctypes.c_void_p
        lib.hws_open.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_char_p, ctypes.POINTER(ctypes.c_int)]
        lib.hws_close.argtypes = [ctypes.c_void_p]
        lib.hws_close.restype = None
        for name in ("hws_start", "hws_stop", "hws_clear"):
            getattr(lib, name).argtypes = [ctypes.c_void_p]
            getattr(lib, name).restype = ctypes.c_int
        lib.hws_sensor_count.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_int), ctypes.POINTER(ctypes.c_int)]
        lib.hws_sensor_name.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_int]
        lib.hws_status.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_int), _LLP, _LLP]
        lib.hws_stats.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_int, _DP, _DP, _DP, _DP, _DP, _LLP, _LLP]
        self.features = int(lib.hws_features())
        if self.features & FEATURE_GLOBAL:
            lib.hws_global_fetch.argtypes = [ctypes.c_void_p, _LLP, _LLP]
            lib.hws_global_copy.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_longlong, ctypes.c_longlong,
                                            _DP]
            lib.hws_global_copy.restype = ctypes.c_longlong

    def open(self, host: str | None = None, user: str | None = None, password: str | None = None) -> int:
        """``hdeem_init``; returns the handle. Raises :class:`HdeemError` with init's code."""
        err = ctypes.c_int(0)
        enc = [s.encode() if s else None for s in (host, user, password)]
        handle = self._lib.hws_open(enc[0], enc[1], enc[2], ctypes.byref(err))
        if not handle:
            raise HdeemError("hdeem_init", err.value)
        return int(handle)

    def close(self, handle: int) -> None:
        """``hdeem_close`` (its result, if any, is not used) and free the handle."""
        self._lib.hws_close(ctypes.c_void_p(handle))

    def sensor_names(self, handle: int) -> list[str]:
        """Sensor names as the library spells them, blade sensors first."""
        nb, nv = self.sensor_count(handle)
        names = []
        buf = ctypes.create_string_buffer(128)
        for i in range(nb + nv):
            self._lib.hws_sensor_name(ctypes.c_void_p(handle), i, buf, len(buf))
            names.append(buf.value.decode(errors="replace"))
        return names

    def sensor_count(self, handle: int) -> tuple[int, int]:
        """(blade sensors, VR sensors)."""
        nb, nv = ctypes.c_int(0), ctypes.c_int(0)
        self._lib.hws_sensor_count(ctypes.c_void_p(handle), ctypes.byref(nb), ctypes.byref(nv))
        return nb.value, nv.value

    def start(self, handle: int) -> int:
        """``hdeem_start``'s code."""
        return int(self._lib.hws_start(ctypes.c_void_p(handle)))

    def stop(self, handle: int) -> int:
        """``hdeem_stop``'s code (asynchronous: poll :meth:`status`)."""
        return int(self._lib.hws_stop(ctypes.c_void_p(handle)))

    def clear(self, handle: int) -> int:
        """``hdeem_clear``'s code."""
        return int(self._lib.hws_clear(ctypes.c_void_p(handle)))

    def status(self, handle: int) -> StatusReading:
        """``hdeem_check_status``. Raises :class:`HdeemError`."""
        flags = ctypes.c_int(0)
        start, stop = ctypes.c_longlong(0), ctypes.c_longlong(0)
        rc = self._lib.hws_status(ctypes.c_void_p(handle), ctypes.byref(flags), ctypes.byref(start),
                                  ctypes.byref(stop))
        if rc != 0:
            raise HdeemError("hdeem_check_status", rc)
        timed = bool(self.features & FEATURE_STATUS_TIMES)
        return StatusReading(flags.value, start.value if timed else None, stop.value if timed else None)

    def stats(self, handle: int, total: bool, n: int) -> StatsReading:
        """``hdeem_get_stats_total`` (``total``) or ``hdeem_get_stats``. Raises :class:`HdeemError`."""
        arrays = [np.zeros(n) for _ in range(5)]
        counts = (ctypes.c_longlong * 2)()
        read = (ctypes.c_longlong * 2)()
        ptrs = [a.ctypes.data_as(_DP) for a in arrays]
        rc = self._lib.hws_stats(ctypes.c_void_p(handle), int(total), n, *ptrs, counts, read)
        if rc != 0:
            raise HdeemError("hdeem_get_stats_total" if total else "hdeem_get_stats", rc)
        return StatsReading(arrays[0], arrays[1], arrays[2], arrays[3], arrays[4], counts=(counts[0], counts[1]),
                            read_ns=(read[0], read[1]))

    def global_fetch(self, handle: int) -> tuple[tuple[int, int], int]:
        """``hdeem_get_global``, kept in the handle: ((blade count, vr count), index since start of the
        first blade sample held, 1-based). Needs the global set (:data:`FEATURE_GLOBAL`)."""
        counts = (ctypes.c_longlong * 2)()
        first = ctypes.c_longlong(0)
        rc = self._lib.hws_global_fetch(ctypes.c_void_p(handle), counts, ctypes.byref(first))
        if rc != 0:
            raise HdeemError("hdeem_get_global", rc)
        return (counts[0], counts[1]), first.value

    def global_copy(self, handle: int, sensor: int, start: int, count: int) -> np.ndarray:
        """Samples ``[start, start+count)`` of ``sensor`` from the kept global reading (W)."""
        out = np.zeros(max(0, count))
        got = self._lib.hws_global_copy(ctypes.c_void_p(handle), sensor, start, count, out.ctypes.data_as(_DP))
        return out[: max(0, int(got))]
