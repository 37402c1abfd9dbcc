"""The daemon's settings: one typed object, from a TOML file, then the environment, then flags.

Precedence, lowest to highest: the defaults below, the TOML file (``--config FILE``; keys at the
top level or in a ``[daemon]`` table), ``HDEEM_WATCH_<FIELD>`` environment variables (e.g.
``HDEEM_WATCH_SOURCE=rapl``, ``HDEEM_WATCH_POLL_INTERVAL_S=0.05``), then command-line flags.
Unknown keys and values of the wrong type are :class:`~hdeem_watch.errors.InputError` naming the
file, key and value. Every field is documented in :class:`DaemonSettings` (and in
``daemon/hdeem-watchd.toml``). The ``[node]`` table describes the hardware where it cannot be
detected (:mod:`hdeem_watch.node.overrides`; docs/your-node.md); the node's name is then its
``name`` key (or ``node`` in ``[daemon]``), since TOML cannot hold a top-level ``node = "NAME"``
beside the table — the older top-level ``node = "NAME"`` still names the node.

Example:
    >>> s = load_settings(env={"HDEEM_WATCH_SPEED": "4"}, overrides={"node": "n7"})
    >>> s.source, s.speed, s.node
    ('sim', 4.0, 'n7')
"""

from __future__ import annotations

import dataclasses
import os
import re
import socket
import tomllib
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hdeem_watch.addresses import is_loopback
from hdeem_watch.errors import InputError

ENV_PREFIX = "HDEEM_WATCH_"


#: Tables of the daemon's config file that other commands read (the daemon leaves them alone).
OTHER_TABLES = ("metricq",)


class SettingError(InputError):
    """A setting with a value out of range; :func:`load_settings` adds where the value came from.

    Attributes:
        setting: the field name.
    """

    def __init__(self, setting: str, message: str) -> None:
        super().__init__(message)
        self.setting = setting
SOURCE_KINDS = ("sim", "hdeem", "rapl", "replay")
#: The largest value a ZeroMQ integer option (and a C int) holds.
MAX_C_INT = 2**31 - 1
#: The fastest the sim or a replay may run (beyond it the sim's clock overflows within a poll).
MAX_SPEED = 1e6
#: Settings whose command-line flag is not ``--`` + the field name with dashes.
FLAG_NAMES = {"prometheus_port": "--prometheus", "record_file": "--record", "poll_interval_s": "--poll-interval",
              "curve_secret_key_file": "--curve-secret-key", "curve_clients_dir": "--curve-clients"}


def default_node() -> str:
    """The short host name (``node123`` of ``node123.cluster.example``)."""
    return socket.gethostname().split(".")[0] or "localhost"


def default_state_dir() -> str:
    """``$STATE_DIRECTORY`` (systemd), else ``$XDG_STATE_HOME/hdeem-watch``, else ``~/.local/state/hdeem-watch``."""
    systemd = os.environ.get("STATE_DIRECTORY")
    if systemd:
        return systemd.split(":")[0]
    xdg = os.environ.get("XDG_STATE_HOME")
    base = Path(xdg) if xdg else Path.home() / ".local" / "state"
    return str(base / "hdeem-watch")


@dataclass(frozen=True)
class DaemonSettings:
    """Everything the node daemon can be told.

    Attributes:
        source: ``sim`` (modelled node, the default), ``hdeem``, ``rapl`` or ``replay``.
        node: node name used in topics and records (default: the short host name).
        pub: stream (PUB) endpoint; default ``ipc://<runtime_dir>/pub.sock``. ``tcp://host:port`` for
            remote subscribers.
        control: control (ROUTER) endpoint; default ``ipc://<runtime_dir>/control.sock``.
        remote_control: a second control endpoint for other nodes, served beside ``control``
            (e.g. ``tcp://*:5591`` with CURVE, while local users and the SLURM hooks keep the ipc
            socket, where the kernel tells who they are); None = only ``control``.
        runtime_dir: directory of the default ipc sockets (created mode 0750, sockets 0660); default
            ``$RUNTIME_DIRECTORY``, ``$XDG_RUNTIME_DIR/hdeem-watch`` or ``/tmp/hdeem-watch-<uid>``.
        state_dir: directory of ``state.db`` (runs, fits, baselines); default ``$STATE_DIRECTORY``,
            ``$XDG_STATE_HOME/hdeem-watch`` or ``~/.local/state/hdeem-watch``.
        poll_interval_s: period of the source poll and of the sample batches (smaller = lower latency,
            more CPU; 40 ms keeps the p99 sensor→subscriber latency ≤ 50 ms at HDEEM's rate).
        idle_poll_interval_s: poll period while nobody watches, for a source that states no quiet
            limit (the built-in ones do, and are polled at half of it:
            :mod:`hdeem_watch.daemon.shell.poll_policy`). 0 = always ``poll_interval_s``.
        heartbeat_s: period of the ``status`` heartbeat.
        republish_s: period at which ``calib`` and ``baseline`` are re-published for late joiners.
        speed: time factor of the ``sim`` and ``replay`` sources (1 = real time).
        seed: random seed of the ``sim`` source (None = fixed default of the sim).
        sim_age: aging of DIMM pairs of the ``sim`` source, ``PAIR=±X%/h`` comma-separated, with an
            optional start ``@<n>s|min|h`` in sim time (None = no aging).
        sim_node: the node the ``sim`` source simulates: ``haswell`` (Taurus' Haswell-EP, HDEEM's
            DIMM pairs) or ``ddr5`` (2 sockets × 8 DDR5 channels, RAPL DRAM per socket).
        replay_file: recording played by the ``replay`` source.
        replay_loop: start the recording again at its end.
        record_file: append every sample the daemon receives to this recording (the replay
            source's CSV format), for post-mortem analysis and demos (None = off).
        rapl_root: powercap root of the ``rapl`` source (default ``/sys/class/powercap``).
        rapl_method: ``auto`` (powercap, else the perf ``power`` PMU), ``powercap`` or ``perf``.
        hdeem_include_dir: directory of the real ``hdeem.h`` (``hdeem`` source).
        hdeem_lib_dir: directory of ``libhdeem.so`` (``hdeem`` source).
        hdeem_lib_names: libhdeem file names looked for in ``hdeem_lib_dir``, comma-separated
            (None = ``libhdeem.so,libhdeem.so.1,libhdeem.a``).
        hdeem_method: ``energy`` (totals since power-on, ΔE/Δt per read; default) or ``global``
            (the running measurement's samples at the native rates).
        hdeem_own_measurement: start, re-arm and stop the HDEEM measurement. Default false: the
            daemon never calls hdeem_start/clear/stop (they belong to the node's users, e.g.
            Score-P's HDEEM plugin); true destroys any other tool's measurement (docs/sources.md).
        hdeem_bmc_host, hdeem_bmc_user: out-of-band access to the BMC (e.g. ``NODE-bmc``); None = in-band.
        hdeem_bmc_password_file: file holding the BMC password (mode 0600/0400; never logged).
        hdeem_cflags: extra compiler flags for the shim (shell words), e.g. ``-DHWS_NO_GPIO_FIELDS``.
        hdeem_poll_interval_s: read the BMC at most this often (None = the idle poll period, ≥ 0.1 s).
        memspec: preset name or DRAMPower JSON file of one DIMM, used for the run model (None:
            ``[node] memspec``, else the preset chosen from the node's DIMMs, else
            ``samsung-m393a1g43db0-cpb``; the daemon logs which and why).
        dimms: DIMMs on the node (the measured DRAM energy is the sum of all DRAM channels).
        currents: the currents the embedded calibrator fits.
        half_life_s: forgetting half-life of the online calibrator (0 = no forgetting).
        physical_rules: the calibrator keeps the ordering rules between calibrated currents
            (IDD3N ≥ IDD2N, IDD0 above the tRAS/tRC mix, ...): no negative energy component, at
            some accuracy (docs/calibration.md). Default false: effective currents.
        model_max_requests: request-prefix size of the kernel model (None = the model's default).
        curve_secret_key_file: the daemon's CURVE certificate (``.key_secret``, see ``--gen-keys``): both
            sockets then encrypt and authenticate (for remote TCP); None = off.
        curve_clients_dir: directory of the public ``.key`` files of the clients allowed to connect
            under CURVE (None = any client that knows the daemon's public key). A file named
            ``<user>.key`` or ``<user>@<label>.key`` registers that key for the local user ``<user>``
            (who may then change state over TCP as on ipc; docs/daemon.md, "Authorization").
        curve_public_key_file: the daemon's public key (``.key``) as clients on this node read it
            (``tui``, ``bench``, ``jobs`` take it from this file); default the ``.key`` beside
            ``curve_secret_key_file``.
        allow_insecure_tcp: accept ``pub``/``control`` on TCP at a non-loopback address without
            CURVE (anyone who reaches the port reads the stream, or starts runs and resets the
            calibration); refused unless true, and warned about loudly when true.
        prometheus_port: serve Prometheus metrics on this port (None = off).
        prometheus_addr: address of the Prometheus endpoint.
        sndhwm: per-subscriber send queue in messages; a slower subscriber loses messages (seen as
            gaps in ``seq``) instead of stalling the daemon.
        quiet_window_s: length of a quiet period taken as an idle baseline.
        quiet_max_spread_w: largest standard deviation of a quiet window (absolute, W).
        quiet_history_s: seconds of samples kept per DRAM channel to look for quiet periods.
        log_level: ``debug``, ``info``, ``warning`` or ``error``.
        node_table: the config file's ``[node]`` table as parsed TOML (sockets, channels, DIMMs,
            memspec, sensors: docs/your-node.md); file only (no environment variable or flag).
        counters: where each window's DRAM commands come from: ``auto`` (the default: the power
            source's own counters when the daemon can open them, else none; the choice is logged
            once at start), ``none`` (the kernel model only),
            ``sim`` (the simulated node's memory-controller counters; needs ``source = "sim"``),
            ``perf`` (the host's ``uncore_imc`` PMUs through ``perf_event_open``; needs
            ``CAP_PERFMON`` or ``perf_event_paranoid <= 0``) or ``replay`` (docs/counters.md).
        job_checkpoint_s: period at which the open SLURM jobs' energy so far is stored (what a
            ``kill -9`` of the daemon may lose of a job; docs/slurm.md).
    """

    source: str = "sim"
    node: str = field(default_factory=default_node)
    pub: str | None = None
    control: str | None = None
    remote_control: str | None = None
    runtime_dir: str | None = None
    state_dir: str = field(default_factory=default_state_dir)
    poll_interval_s: float = 0.04
    idle_poll_interval_s: float = 0.25
    heartbeat_s: float = 1.0
    republish_s: float = 10.0
    speed: float = 1.0
    seed: int | None = None
    sim_age: str | None = None
    sim_node: str = "haswell"
    replay_file: str | None = None
    replay_loop: bool = False
    record_file: str | None = None
    # -- sources (hdeem_watch.sources.options turns these into source options) --
    rapl_root: str | None = None
    rapl_method: str = "auto"
    hdeem_include_dir: str | None = None
    hdeem_lib_dir: str | None = None
    hdeem_lib_names: str | None = None
    hdeem_method: str = "energy"
    hdeem_own_measurement: bool = False
    hdeem_bmc_host: str | None = None
    hdeem_bmc_user: str | None = None
    hdeem_bmc_password_file: str | None = None
    hdeem_cflags: str = ""
    hdeem_poll_interval_s: float | None = None
    memspec: str | None = None
    dimms: int = 8
    currents: tuple[str, ...] = ("idd0", "idd2n", "idd3n", "idd4r", "idd4w")
    half_life_s: float = 0.0
    physical_rules: bool = False
    model_max_requests: int | None = None
    curve_secret_key_file: str | None = None
    curve_clients_dir: str | None = None
    curve_public_key_file: str | None = None
    allow_insecure_tcp: bool = False
    prometheus_port: int | None = None
    prometheus_addr: str = "127.0.0.1"
    sndhwm: int = 20_000
    quiet_window_s: float = 5.0
    quiet_max_spread_w: float = 0.5
    quiet_history_s: float = 60.0
    log_level: str = "info"
    node_table: Mapping[str, Any] | None = None
    counters: str = "auto"
    job_checkpoint_s: float = 5.0

    def __post_init__(self) -> None:
        if self.source not in SOURCE_KINDS:
            raise SettingError("source", f"source = {self.source!r}; expected one of {', '.join(SOURCE_KINDS)}")
        for name in ("poll_interval_s", "heartbeat_s", "republish_s", "speed", "quiet_window_s", "quiet_history_s",
                     "job_checkpoint_s"):
            if not getattr(self, name) > 0:
                raise SettingError(name, f"{name} = {getattr(self, name)!r}; expected a number > 0")
        if self.idle_poll_interval_s < 0:
            raise SettingError("idle_poll_interval_s", f"idle_poll_interval_s = {self.idle_poll_interval_s!r}; expected >= 0 (0 = off)")
        if self.half_life_s < 0:
            raise SettingError("half_life_s", f"half_life_s = {self.half_life_s!r}; expected >= 0 (0 = no forgetting)")
        if self.dimms < 1:
            raise SettingError("dimms", f"dimms = {self.dimms!r}; expected >= 1")
        if not 1 <= self.sndhwm <= MAX_C_INT:
            raise SettingError("sndhwm", f"sndhwm = {self.sndhwm!r}; expected 1..{MAX_C_INT} messages")
        if self.speed > MAX_SPEED:
            raise SettingError("speed", f"speed = {self.speed!r}; expected a time factor up to {MAX_SPEED:g}")

        if self.prometheus_port is not None and not 0 <= self.prometheus_port <= 65535:
            raise SettingError("prometheus_port", f"prometheus_port = {self.prometheus_port!r}; expected 0..65535")
        if self.log_level not in ("debug", "info", "warning", "error"):
            raise SettingError("log_level", f"log_level = {self.log_level!r}; expected debug, info, warning or error")
        if not self.node or "/" in self.node:
            raise SettingError("node", f"node = {self.node!r}; expected a non-empty name without '/'")
        from hdeem_watch.counters.source import COUNTER_KINDS

        if self.counters not in COUNTER_KINDS:
            raise SettingError("counters", f"counters = {self.counters!r}; expected one of {', '.join(COUNTER_KINDS)}")
        if self.counters == "replay" and self.source != "replay":
            raise SettingError("counters", f"counters = 'replay' needs source = 'replay' (not {self.source!r}): the "
                               "counters are played back with the recording they were recorded beside")
        if self.counters == "sim" and self.source != "sim":
            raise SettingError("counters", f"counters = 'sim' needs source = 'sim' (not {self.source!r}): only the "
                               "simulated node has simulated memory controllers")
        if self.source == "replay" and not self.replay_file:
            raise SettingError("replay_file", "source = 'replay' needs replay_file (--replay-file FILE)")
        if self.seed is not None and not 0 <= self.seed < 2**63:
            raise SettingError("seed", f"seed = {self.seed!r}; expected an integer >= 0")
        if not self.currents:
            raise SettingError("currents", "currents = []; expected at least one current to calibrate")
        for name in ("pub", "control", "remote_control"):
            endpoint = getattr(self, name)
            if (endpoint and not is_loopback(endpoint) and not self.curve_secret_key_file
                    and not self.allow_insecure_tcp):
                raise SettingError(name, f"{name} = {endpoint!r}: TCP on a non-loopback address without CURVE is "
                                   "open to anyone who can reach it; set curve_secret_key_file (see --gen-keys), "
                                   "or allow_insecure_tcp = true to accept that")
        from hdeem_watch.sim.layout import sim_node

        try:
            sim_node(self.sim_node)
        except InputError as error:
            raise SettingError("sim_node", str(error)) from None
        if self.sim_age:
            from hdeem_watch.sim.age import parse_sim_age

            try:
                parse_sim_age(self.sim_age)
            except InputError as error:
                raise SettingError("sim_age", str(error)) from None
        from hdeem_watch.sources import options as source_settings

        source_settings.validate(self)
        if self.node_table is not None:
            try:
                self.node_overrides()
            except InputError as error:
                raise SettingError("node_table", str(error)) from None

    def node_overrides(self) -> Any:
        """The parsed ``[node]`` table (a :class:`~hdeem_watch.node.overrides.NodeOverrides`), or None."""
        if self.node_table is None:
            return None
        from hdeem_watch.node.overrides import parse_node_table

        return parse_node_table(self.node_table)

    def source_options(self) -> dict[str, Any]:
        """Keyword options for ``make_source(self.source, ...)``."""
        if self.source == "sim":
            from hdeem_watch.sim.layout import sim_node

            options: dict[str, Any] = {"speed": self.speed, "layout": sim_node(self.sim_node)}
            if self.seed is not None:
                options["seed"] = self.seed
            if self.sim_age:
                from hdeem_watch.sim.age import sim_age_options

                options.update(sim_age_options(self.sim_age))
            overrides = self.node_overrides()
            if overrides is not None and overrides.counts:  # the sim models the [node] table's node
                from hdeem_watch.node.overrides import apply_overrides
                from hdeem_watch.node.setup import configured_only

                options["node"] = apply_overrides(configured_only("the simulated node"), overrides)
            return options
        if self.source == "replay":
            return {"path": self.replay_file, "speed": self.speed, "loop": self.replay_loop}
        from hdeem_watch.sources import options as source_settings

        if self.source == "rapl":
            return source_settings.rapl_options(self)
        return source_settings.hdeem_options(self)


_FIELDS = {f.name: f for f in dataclasses.fields(DaemonSettings)}
#: Fields only a config file's table sets (``[node]``): not keys, variables or flags of their own.
_TABLE_FIELDS = ("node_table",)


def _coerce(name: str, value: Any, where: str) -> Any:
    """``value`` converted to the type of field ``name`` (strings from the environment parsed)."""
    hint = typing.get_type_hints(DaemonSettings)[name]
    args = typing.get_args(hint)
    optional = isinstance(hint, types.UnionType) and type(None) in args
    base = next((a for a in args if a is not type(None)), hint) if optional else hint
    if value is None or (optional and isinstance(value, str) and value.lower() in ("", "none", "null")):
        if optional:
            return None
        raise InputError(f"{where}: {name} must not be empty")
    try:
        if base is bool:
            if isinstance(value, bool):
                return value
            if isinstance(value, str) and value.lower() in ("1", "true", "yes", "on", "0", "false", "no", "off"):
                return value.lower() in ("1", "true", "yes", "on")
            raise ValueError
        if base is int:
            if isinstance(value, bool | float):
                raise ValueError
            return int(value)
        if base is float:
            if isinstance(value, bool):
                raise ValueError
            return float(value)
        if base is str:
            if not isinstance(value, str):  # node = 5 is a mistake, not the node "5"
                raise ValueError
            return value
        if typing.get_origin(base) is tuple:
            items = value.split(",") if isinstance(value, str) else value
            if not isinstance(items, list | tuple) or not all(isinstance(i, str) for i in items):
                raise ValueError
            return tuple(i.strip().lower() for i in items if i.strip())
    except (TypeError, ValueError):
        pass
    else:
        return value
    expected = "a string in quotes" if base is str else getattr(base, "__name__", str(base))
    raise InputError(f"{where}: {name} = {value!r}; expected {expected}")


def _apply(values: dict[str, Any], data: Mapping[str, Any], where: str, origins: dict[str, str]) -> None:
    for key, value in data.items():
        name = key.replace("-", "_")
        if name not in _FIELDS or name in _TABLE_FIELDS:
            known = sorted(set(_FIELDS) - set(_TABLE_FIELDS))
            raise InputError(f"{where}: unknown setting {key!r}; expected one of {', '.join(known)}")
        values[name] = _coerce(name, value, where)
        origins[name] = where


def read_config_file(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The TOML config file as a dict (every table; the daemon's and the other commands').

    Raises:
        InputError: one line naming the file: unreadable, not UTF-8 text, or not valid TOML.
    """
    path = Path(path)
    text = ""
    try:
        text = path.read_text(encoding="utf-8")
        return tomllib.loads(text)
    except OSError as error:
        raise InputError(f"{path}: cannot read the config file ({error.strerror})") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file (not UTF-8); expected a TOML config file") from None
    except tomllib.TOMLDecodeError as error:
        hint = ""
        if re.search(r"(?m)^\s*node\s*=", text) and re.search(r"(?m)^\s*\[\s*node\s*[\].]", text):
            hint = ("; a top-level node = \"NAME\" and a [node] table cannot both be in one file: "
                    "write the name as name = \"NAME\" inside [node]")
        raise InputError(f"{path}: not valid TOML ({error}){hint}") from None


def load_settings(
    config: str | os.PathLike[str] | None = None,
    *,
    env: Mapping[str, str] | None = None,
    overrides: Mapping[str, Any] | None = None,
    check_model: bool = False,
) -> DaemonSettings:
    """Settings from defaults, the TOML file, ``HDEEM_WATCH_*`` variables and ``overrides`` (flags).

    Args:
        config: TOML file (top-level keys or a ``[daemon]`` table), or None.
        env: the environment (default ``os.environ``); only ``HDEEM_WATCH_<FIELD>`` names are read,
            other ``HDEEM_WATCH_`` variables (e.g. ``HDEEM_WATCH_RUNTIME_DIR``) map to fields too.
        overrides: command-line values; None values are ignored (flag not given).
        check_model: also check the run model's settings (:func:`check_model_settings`; loads the
            memspec), as the daemon does at start.

    Raises:
        InputError: unreadable file, bad TOML, unknown key, value of the wrong type or range.
    """
    values: dict[str, Any] = {}
    origins: dict[str, str] = {}
    if config is not None:
        path = Path(config)
        data = read_config_file(path)
        # [metricq] belongs to `hdeem-watch metricq-source`, which reads the same file.
        own = {k: v for k, v in data.items() if k not in OTHER_TABLES}
        from hdeem_watch.node.overrides import split_node_entry

        entry = own.pop("node", None)
        table, name = split_node_entry(entry)
        if name is not None or (entry is not None and table is None):  # node = "NAME" (or a wrong value)
            _apply(values, {"node": entry if table is None else name}, f"{path} [node]" if table else str(path), origins)
        if table is not None:
            values["node_table"] = dict(table)
            origins["node_table"] = str(path)
        if "daemon" in own and isinstance(own["daemon"], dict):
            if "node" in values and "node" in own["daemon"]:
                raise InputError(f"{path}: node is set twice, at the top ({values['node']!r}) and in [daemon] "
                                 f"({own['daemon']['node']!r}); expected one of them")
            rest = {k: v for k, v in own.items() if k != "daemon"}
            _apply(values, rest, str(path), origins)
            _apply(values, own["daemon"], f"{path} [daemon]", origins)
        else:
            _apply(values, own, str(path), origins)
    environment = os.environ if env is None else env
    for name in _FIELDS:
        if name in _TABLE_FIELDS:
            continue
        key = ENV_PREFIX + name.upper()
        if key in environment:
            values[name] = _coerce(name, environment[key], f"environment {key}")
            origins[name] = f"environment {key}"
    if overrides:
        for name, value in overrides.items():
            if value is not None:
                if name not in _FIELDS or name in _TABLE_FIELDS:
                    raise InputError(f"unknown setting {name!r}")
                flag = FLAG_NAMES.get(name, f"--{name.replace('_', '-')}")
                values[name] = _coerce(name, value, flag)
                origins[name] = flag
    try:
        settings = DaemonSettings(**values)
        if check_model:
            check_model_settings(settings)
    except SettingError as error:
        where = origins.get(error.setting)
        raise InputError(f"{where}: {error}" if where else str(error)) from None
    return settings


def check_model_settings(settings: DaemonSettings) -> None:
    """Check the run model's settings: the memspec exists and the currents are known to it.

    Loads the memspec (a preset name or a DRAMPower JSON file), so a typo stops the daemon at once
    instead of leaving every run without a model.

    Raises:
        SettingError: naming the setting, its value and what was expected.
    """
    from hdeem_watch.dram.energy import CURRENT_NAMES
    from hdeem_watch.dram.memspec import memspec_from
    from hdeem_watch.node.setup import DEFAULT_MEMSPEC

    overrides = settings.node_overrides()
    setting, name = "memspec", settings.memspec or DEFAULT_MEMSPEC  # None: chosen from the DIMMs at start
    if overrides is not None and overrides.memspec:
        setting, name = "node_table", overrides.memspec
    try:
        spec = memspec_from(name)
    except InputError as error:
        key = "[node].memspec" if setting == "node_table" else "memspec"
        raise SettingError(setting, f"{key} = {name!r}: {error}") from None
    known = [name for name in CURRENT_NAMES if name in spec.currents]
    unknown = [name for name in settings.currents if name not in known]
    if unknown:
        raise SettingError("currents", f"currents: unknown current {unknown[0]!r}; expected some of {', '.join(known)}")
