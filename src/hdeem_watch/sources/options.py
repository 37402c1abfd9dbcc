"""The sources' settings: daemon settings → ``make_source`` options, command-line flags, checks.

:mod:`hdeem_watch.config` holds the fields (TOML keys, ``HDEEM_WATCH_*`` variables); this module
turns them into the options of the hdeem and rapl sources, validates them, reads the BMC password
file (its mode checked, its content never logged), and defines the matching command-line flags
(``add_source_flags`` / ``source_flag_overrides`` for ``hdeem-watch daemon``).

ΔE/Δt sources (rapl, hdeem's energy method) publish one sample per read, so their nominal rate is
their read rate: unless set, the read interval is the slowest poll period of the daemon (its idle
poll), so an idle daemon does not see "missing" samples between reads that are merely slower than a
nominal 10 Sa/s (issue 22.12).

Example:
    >>> from types import SimpleNamespace
    >>> delta_source_interval_s(SimpleNamespace(poll_interval_s=0.04, idle_poll_interval_s=0.25), None)
    0.25
"""

from __future__ import annotations

import argparse
import os
import shlex
import stat
from typing import Any

from hdeem_watch.errors import InputError

HDEEM_METHODS = ("energy", "global")
RAPL_METHODS = ("auto", "powercap", "perf")
#: The shortest read interval of a ΔE/Δt source (the counters' resolution makes faster reads noise).
MIN_DELTA_INTERVAL_S = 0.1


def delta_source_interval_s(settings: Any, configured: float | None) -> float:
    """Read interval of a ΔE/Δt source: ``configured``, else the daemon's slowest poll period
    (at least :data:`MIN_DELTA_INTERVAL_S`)."""
    if configured is not None:
        return float(configured)
    return max(MIN_DELTA_INTERVAL_S, float(settings.poll_interval_s), float(settings.idle_poll_interval_s or 0))


def read_password_file(path: str) -> str:
    """The BMC password from ``path`` (first line, stripped).

    Raises:
        InputError: unreadable, or readable/writable by group or others (names the file and mode,
            never the content).
    """
    where = f"hdeem_bmc_password_file {path}"
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
    except OSError as error:
        raise InputError(f"{where}: cannot open ({error.strerror})") from None
    with os.fdopen(fd, encoding="utf-8", errors="strict") as fh:
        info = os.fstat(fh.fileno())
        if not stat.S_ISREG(info.st_mode):
            raise InputError(f"{where}: not a regular file")
        if info.st_mode & 0o077:
            raise InputError(f"{where}: mode {stat.S_IMODE(info.st_mode):04o} lets group or others read it; "
                             "expected 0600 or 0400 (chmod 600)")
        try:
            text = fh.read(4096)
        except UnicodeDecodeError:
            raise InputError(f"{where}: not UTF-8 text") from None
    password = text.splitlines()[0].strip() if text.strip() else ""
    if not password:
        raise InputError(f"{where}: empty")
    return password


def validate(settings: Any) -> None:
    """Check the source fields of the settings. Raises :class:`InputError` naming key and value."""
    if settings.hdeem_method not in HDEEM_METHODS:
        raise InputError(f"hdeem_method = {settings.hdeem_method!r}; expected one of {', '.join(HDEEM_METHODS)}")
    if settings.rapl_method not in RAPL_METHODS:
        raise InputError(f"rapl_method = {settings.rapl_method!r}; expected one of {', '.join(RAPL_METHODS)}")
    interval = settings.hdeem_poll_interval_s
    if interval is not None and not interval > 0:
        raise InputError(f"hdeem_poll_interval_s = {interval!r}; expected a number > 0 (s)")
    if (settings.hdeem_bmc_user or settings.hdeem_bmc_password_file) and not settings.hdeem_bmc_host:
        raise InputError("hdeem_bmc_user / hdeem_bmc_password_file need hdeem_bmc_host (out-of-band access)")
    try:
        shlex.split(settings.hdeem_cflags or "")
    except ValueError as error:
        raise InputError(f"hdeem_cflags = {settings.hdeem_cflags!r}: {error}") from None


def hdeem_options(settings: Any) -> dict[str, Any]:
    """Options of ``make_source("hdeem", ...)`` from the settings (reads the password file)."""
    options: dict[str, Any] = {
        "method": settings.hdeem_method,
        "own_measurement": bool(settings.hdeem_own_measurement),
        "interval_s": delta_source_interval_s(settings, settings.hdeem_poll_interval_s),
    }
    if settings.hdeem_include_dir:
        options["include_dir"] = settings.hdeem_include_dir
    if settings.hdeem_lib_dir:
        options["lib_dir"] = settings.hdeem_lib_dir
    if settings.hdeem_cflags:
        options["cflags"] = tuple(shlex.split(settings.hdeem_cflags))
    if settings.hdeem_lib_names:
        options["lib_names"] = tuple(n.strip() for n in settings.hdeem_lib_names.split(",") if n.strip())
    if settings.hdeem_bmc_host:
        options["host"] = settings.hdeem_bmc_host
        options["user"] = settings.hdeem_bmc_user
        if settings.hdeem_bmc_password_file:
            options["password"] = read_password_file(settings.hdeem_bmc_password_file)
    return options


def rapl_options(settings: Any) -> dict[str, Any]:
    """Options of ``make_source("rapl", ...)`` from the settings."""
    options: dict[str, Any] = {"interval_s": delta_source_interval_s(settings, None),
                               "method": settings.rapl_method}
    if settings.rapl_root is not None:
        options["root"] = settings.rapl_root
    return options


#: flag → settings field, for the sources' command-line flags.
_FLAGS = {
    "--rapl-root": ("rapl_root", "DIR", "powercap root of the rapl source (default /sys/class/powercap)"),
    "--rapl-method": ("rapl_method", "METHOD", "rapl: powercap, perf (the power PMU) or auto (default)"),
    "--hdeem-method": ("hdeem_method", "METHOD", "hdeem: energy (totals since power-on, default) or global"),
    "--hdeem-include-dir": ("hdeem_include_dir", "DIR", "hdeem: directory of hdeem.h"),
    "--hdeem-lib-dir": ("hdeem_lib_dir", "DIR", "hdeem: directory of libhdeem"),
    "--hdeem-lib-names": ("hdeem_lib_names", "NAMES", "hdeem: libhdeem file names to look for, comma-separated"),
    "--hdeem-cflags": ("hdeem_cflags", "FLAGS", "hdeem: extra compiler flags for the shim, e.g. -DHWS_NO_GPIO_FIELDS"),
    "--hdeem-bmc-host": ("hdeem_bmc_host", "HOST", "hdeem: BMC host for out-of-band access (e.g. NODE-bmc)"),
    "--hdeem-bmc-user": ("hdeem_bmc_user", "USER", "hdeem: BMC user (out-of-band)"),
    "--hdeem-bmc-password-file": ("hdeem_bmc_password_file", "FILE", "hdeem: file holding the BMC password "
                                  "(mode 0600)"),
    "--hdeem-poll-interval": ("hdeem_poll_interval_s", "S", "hdeem: read the BMC at most every S seconds"),
}


def add_source_flags(parser: argparse.ArgumentParser) -> None:
    """Add the sources' flags (``--rapl-root``, ``--hdeem-*``) to ``parser``."""
    for flag, (dest, metavar, text) in _FLAGS.items():
        parser.add_argument(flag, dest=dest, metavar=metavar, help=text)
    parser.add_argument("--hdeem-own-measurement", dest="hdeem_own_measurement", action="store_const", const=True,
                        help="hdeem: start, re-arm and stop the HDEEM measurement (destroys other tools' "
                        "measurements; default: leave it alone)")


def source_flag_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """The settings overrides given by the sources' flags (None = not given)."""
    names = [dest for dest, _, _ in _FLAGS.values()] + ["hdeem_own_measurement"]
    return {name: getattr(args, name, None) for name in names}

