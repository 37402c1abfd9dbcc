"""Settings of ``hdeem-watch metricq-source``: the ``[metricq]`` table, the environment, flags.

Precedence, lowest to highest: the defaults of :class:`SourceSettings`, the ``[metricq]`` table of
the TOML file (``--config FILE``, the daemon's config file; other tables are not read here),
``HDEEM_WATCH_METRICQ_<FIELD>`` environment variables (e.g. ``HDEEM_WATCH_METRICQ_PREFIX``), then
command-line flags.

Credentials: the AMQP URL (``server``) carries the broker's user and password, the ``token`` names
this source to the MetricQ manager. Either can come from a file (``server_file``, ``token_file``)
that must not be readable by group or others (:func:`read_secret_file`).

Example:
    >>> s = load_source_settings(env={"HDEEM_WATCH_METRICQ_SERVER": "amqp://localhost/"},
    ...                          overrides={"prefix": "taurus.hdeem"})
    >>> s.server, s.prefix, s.metrics
    ('amqp://localhost/', 'taurus.hdeem', ('power', 'above_baseline', 'calibrated_currents'))
"""

from __future__ import annotations

import os
import socket
import stat
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

from hdeem_watch.config import read_config_file
from hdeem_watch.errors import InputError
from hdeem_watch.metricq.naming import FAMILIES, check_prefix

ENV_PREFIX = "HDEEM_WATCH_METRICQ_"
TABLE = "metricq"


@dataclass(frozen=True)
class SourceSettings:
    """Everything the MetricQ source needs.

    Attributes:
        server: AMQP URL of the MetricQ management broker (``amqp://user:password@host/vhost``).
        server_file: a file holding the URL (permissions checked); used when ``server`` is empty.
        token: this source's MetricQ token (its identity at the manager; unique per source, as its
            RPC queue is exclusive); default ``source-hdeem-watch-<short host name>``.
        token_file: a file holding the token (permissions checked); used when ``token`` is empty.
        prefix: the site prefix of every metric name.
        metrics: the metric families to publish (``power``, ``above_baseline``, ``calibrated_currents``).
        connect: the daemon's stream endpoint (default: the local daemon's ipc socket).
        reconnect_max_s: the longest wait between two attempts to reach MetricQ (backoff doubles up to it).
        buffer_points: data points kept while MetricQ is unreachable (the oldest go first beyond it).
        status_file: where to write the status as JSON (refreshed every ``status_interval_s``); "" = nowhere.
        status_interval_s: how often the status is logged and written.
        daemon_silence_s: the daemon counts as silent after this long without a message.
        curve_server_key_file: the daemons' public CURVE certificate (``server.key``) for TCP
            streams of daemons running with CURVE; "" = plain.
        curve_client_key_file: this source's secret certificate (``.key_secret``) when the daemons
            admit listed clients only; "" = an ephemeral key pair.
    """

    server: str = ""
    server_file: str = ""
    token: str = ""
    token_file: str = ""
    prefix: str = "hdeem"
    metrics: tuple[str, ...] = FAMILIES
    connect: str = ""
    reconnect_max_s: float = 30.0
    buffer_points: int = 500_000
    status_file: str = ""
    status_interval_s: float = 10.0
    daemon_silence_s: float = 5.0
    curve_server_key_file: str = ""
    curve_client_key_file: str = ""

    def check(self) -> SourceSettings:
        """Return self if every value is in range.

        Raises:
            InputError: naming the setting, its value and what was expected.
        """
        if not self.server:
            raise InputError("metricq server: not set; give --server amqp://USER:PASSWORD@HOST/, "
                             "server = ... in [metricq], or server_file")
        if not self.server.startswith(("amqp://", "amqps://")):
            raise InputError(f"metricq server {_redacted(self.server)!r}: expected an amqp:// or amqps:// URL")
        if not self.token:
            raise InputError("metricq token: empty; expected a name such as 'source-hdeem-watch-node7'")
        check_prefix(self.prefix)
        unknown = [m for m in self.metrics if m not in FAMILIES]
        if unknown or not self.metrics:
            raise InputError(f"metricq metrics {list(self.metrics)}: expected a non-empty list of {list(FAMILIES)}")
        for name in ("reconnect_max_s", "status_interval_s", "daemon_silence_s"):
            if not getattr(self, name) > 0:
                raise InputError(f"metricq {name} = {getattr(self, name)!r}: expected a positive number of seconds")
        if self.buffer_points < 1:
            raise InputError(f"metricq buffer_points = {self.buffer_points!r}: expected a positive integer")
        return self


def _redacted(url: str) -> str:
    """``url`` with its password replaced by ``***``."""
    scheme, sep, rest = url.partition("://")
    credentials, at, host = rest.rpartition("@")
    if not sep or not at or ":" not in credentials:
        return url
    return f"{scheme}://{credentials.split(':', 1)[0]}:***@{host}"


def redacted(url: str) -> str:
    """The URL fit for logs: the password replaced by ``***``.

    Example:
        >>> redacted("amqp://hw:s3cret@rabbit.example/hpc")
        'amqp://hw:***@rabbit.example/hpc'
    """
    return _redacted(url)


def read_secret_file(path: str | os.PathLike[str]) -> str:
    """The stripped text of a credentials file that only its owner may read.

    Raises:
        InputError: missing, not a regular file, readable or writable by group or others, or empty.
    """
    file = Path(path)
    try:
        info = file.stat()
    except OSError as error:
        raise InputError(f"{file}: cannot read the credentials file ({error.strerror})") from None
    if not stat.S_ISREG(info.st_mode):
        raise InputError(f"{file}: not a regular file; expected a credentials file")
    mode = stat.S_IMODE(info.st_mode)
    if mode & 0o077:
        raise InputError(f"{file}: mode {mode:04o} lets group or others read it; "
                         f"expected 0600 or stricter (chmod 600 {file})")
    try:
        text = file.read_text(encoding="utf-8").strip()
    except (OSError, UnicodeDecodeError) as error:
        raise InputError(f"{file}: cannot read the credentials file ({error})") from None
    if not text:
        raise InputError(f"{file}: empty; expected one line")
    return text


_FIELDS = {f.name: f for f in fields(SourceSettings)}


def _coerce(name: str, value: Any, where: str) -> Any:
    default = getattr(SourceSettings(), name)
    if isinstance(default, tuple):
        if isinstance(value, str):
            value = [v.strip() for v in value.split(",") if v.strip()]
        if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
            raise InputError(f"{where}: {value!r}; expected a list of names")
        return tuple(value)
    if isinstance(default, bool) or isinstance(value, bool):
        raise InputError(f"{where}: {value!r}; expected {type(default).__name__}")
    try:
        if isinstance(default, float):
            return float(value)
        if isinstance(default, int):
            if isinstance(value, float) and not value.is_integer():
                raise ValueError(value)
            return int(value)
    except (TypeError, ValueError):
        raise InputError(f"{where}: {value!r}; expected a number") from None
    if not isinstance(value, str):
        raise InputError(f"{where}: {value!r}; expected a string")
    return value


def _table(config: str | os.PathLike[str]) -> Mapping[str, Any]:
    path = Path(config)
    data = read_config_file(path)
    table = data.get(TABLE, {})
    if not isinstance(table, dict):
        raise InputError(f"{path}: [{TABLE}] is not a table")
    return table


def load_source_settings(
    config: str | os.PathLike[str] | None = None,
    *,
    env: Mapping[str, str] | None = None,
    overrides: Mapping[str, Any] | None = None,
) -> SourceSettings:
    """Settings from defaults, the ``[metricq]`` table, ``HDEEM_WATCH_METRICQ_*``, then ``overrides``.

    ``server_file`` / ``token_file`` are read (permissions checked) when ``server`` / ``token``
    is not given at the same or a higher level.

    Raises:
        InputError: unreadable file, bad TOML, unknown key, a value of the wrong type or range, a
            credentials file readable by others.
    """
    values: dict[str, Any] = {}
    layers: list[tuple[str, Mapping[str, Any]]] = []
    if config is not None:
        layers.append((f"{config} [{TABLE}]", _table(config)))
    environment = os.environ if env is None else env
    layers.append(("environment", {k[len(ENV_PREFIX):].lower(): v for k, v in environment.items()
                                   if k.startswith(ENV_PREFIX)}))
    layers.append(("flag", {k: v for k, v in (overrides or {}).items() if v is not None}))
    for where, layer in layers:
        for key, value in layer.items():
            if key not in _FIELDS:
                raise InputError(f"{where}: unknown setting {key!r}; expected one of {sorted(_FIELDS)}")
            label = f"--{key.replace('_', '-')}" if where == "flag" else f"{where} {key}"
            values[key] = _coerce(key, value, label)
            if key in ("server", "token"):
                values.pop(f"{key}_file", None)
            elif key in ("server_file", "token_file"):
                values.pop(key[: -len("_file")], None)
    settings = SourceSettings(**values)
    if settings.server_file and not values.get("server"):
        settings = replace(settings, server=read_secret_file(settings.server_file))
    if settings.token_file and not values.get("token"):
        settings = replace(settings, token=read_secret_file(settings.token_file))
    if not settings.token and "token" not in values:
        settings = replace(settings, token=default_token())
    return settings.check()


def default_token() -> str:
    """``source-hdeem-watch-<short host name>`` (tokens must differ between sources)."""
    host = socket.gethostname().split(".")[0] or "localhost"
    return f"source-hdeem-watch-{host}"
