"""The SLURM Prolog and Epilog: open and close each job's window in the node daemon, safely.

``daemon/slurm/prolog.sh`` and ``epilog.sh`` (run as root by slurmd) call
``python3 -m hdeem_watch.slurm prolog|epilog``, i.e. :func:`prolog` and :func:`epilog`:

* **One source of truth.** The daemon's endpoints and state directory come from the daemon's own
  config file (``$HDEEM_WATCH_CONFIG``, default :data:`SYSTEM_CONFIG`), read by the daemon's own
  settings loader, with the systemd unit's directories (:data:`SYSTEM_RUNTIME_DIR`,
  :data:`SYSTEM_STATE_DIR`) where the file names none. The hooks' own settings (the interpreter,
  the opt-ins) are ``HDEEM_WATCH_*`` variables from ``slurm-hooks.env``.
* **The Prolog** sends ``job.start`` (job id, user, uid, nodes, CPUs); with
  ``HDEEM_WATCH_PROLOG_BASELINE_S`` > 0 it first measures an idle baseline (the job waits that
  long). Only with ``HDEEM_WATCH_START_DAEMON=1`` does it start a daemon when none answers, with
  the same config file — so a daemon that is running but slow cannot get a twin (the state
  directory's lock and the endpoint probe refuse it) — and never one on the ``hdeem`` source
  unless ``HDEEM_WATCH_START_HDEEM=1`` too (it would share the node's HDEEM with its users).
* **The Epilog** sends ``job.stop`` with the exit code; a daemon that does not answer gets the stop
  later: it is kept as ``stop-<job>.json`` and sent (with the job's end time) by the next hook,
  which the daemon uses to close the job as ``interrupted`` when it was down at the job's end. The
  last Epilog stops a daemon the hooks started once no job is open on it.
* **Bounded and quiet.** Every daemon call has a timeout; the shell wrappers add a hard ``timeout``
  and always exit 0 (a failing Prolog drains the node). Failures go to syslog (and stderr). Hook
  data lives in ``<state dir>/slurm-hooks`` (mode 0700), never in the runtime directory (systemd
  removes that when the daemon restarts); the per-job file is removed by the Epilog and the
  hooks' log ``jobs.jsonl`` is rotated at :data:`MAX_LOG_BYTES`.
"""

from __future__ import annotations

import contextlib
import json
import logging
import logging.handlers
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from hdeem_watch.job_record import JobRecord
from hdeem_watch.slurm import allocation_nodes, hook_context, hook_setting

#: The daemon's config file of a system install (``systemd/hdeem-watchd.service``).
SYSTEM_CONFIG = "/etc/hdeem-watch/hdeem-watchd.toml"
#: The unit's ``RuntimeDirectory=`` and ``StateDirectory=``.
SYSTEM_RUNTIME_DIR = "/run/hdeem-watch"
SYSTEM_STATE_DIR = "/var/lib/hdeem-watch"
#: The hooks' directory inside the daemon's state directory.
HOOK_SUBDIR = "slurm-hooks"
#: ``jobs.jsonl`` (and the log of a daemon the hooks started) is rotated beyond this size.
MAX_LOG_BYTES = 1 << 20
#: Stops kept for a daemon that did not answer (the oldest beyond are dropped).
MAX_PENDING_STOPS = 1000
SYSLOG_TAG = "hdeem-watch-slurm"

log = logging.getLogger("hdeem_watch.slurm")


@dataclass(frozen=True)
class HookSettings:
    """Where the daemon is and what the hooks may do (see the module docstring)."""

    config: str | None
    control: str
    pub: str
    state_dir: Path
    source: str
    hook_dir: Path
    start_daemon: bool
    start_hdeem: bool
    baseline_s: float
    timeout_s: float
    start_timeout_s: float


def _number(env: Mapping[str, str], name: str, default: str) -> float:
    raw = hook_setting(name, default, env) or default
    try:
        return float(raw)
    except ValueError:
        _log(f"HDEEM_WATCH_{name.upper()} = {raw!r} is not a number; using {default}", env)
        return float(default)


def hook_settings(env: Mapping[str, str]) -> HookSettings:
    """The hooks' settings: the daemon's from its config file, the hooks' own from ``env``.

    Raises:
        InputError: the config file is unreadable or invalid (the daemon would refuse it too).
    """
    from hdeem_watch.config import load_settings, read_config_file
    from hdeem_watch.wire.client import default_endpoints

    config: str | None = hook_setting("config", SYSTEM_CONFIG, env)
    if config and not Path(config).exists():
        config = None
    settings = load_settings(config, env={})  # the file alone: the hook's environment is SLURM's
    named = read_config_file(config) if config else {}
    table = named["daemon"] if isinstance(named.get("daemon"), dict) else {}
    state_dir = Path(settings.state_dir if "state_dir" in named or "state_dir" in table else SYSTEM_STATE_DIR)
    pub, control = default_endpoints(settings.runtime_dir or SYSTEM_RUNTIME_DIR)
    return HookSettings(
        config=config, control=settings.control or control, pub=settings.pub or pub, state_dir=state_dir,
        source=settings.source, hook_dir=Path(hook_setting("hook_dir", str(state_dir / HOOK_SUBDIR), env)),
        start_daemon=hook_setting("start_daemon", "0", env) == "1",
        start_hdeem=hook_setting("start_hdeem", "0", env) == "1",
        baseline_s=_number(env, "prolog_baseline_s", "0"), timeout_s=_number(env, "hook_call_timeout_s", "10"),
        start_timeout_s=_number(env, "start_timeout_s", "20"))


def local_control_endpoint(env: Mapping[str, str] | None = None) -> str:
    """The control endpoint of this node's daemon for a client: ``$HDEEM_WATCH_CONTROL``, else the
    system daemon's (its config file, as the hooks read it) when that file exists, else the
    per-user default (``hdeem_watch.wire.client.default_endpoints``)."""
    from hdeem_watch.wire.client import default_endpoints

    env = os.environ if env is None else env
    if env.get("HDEEM_WATCH_CONTROL"):
        return env["HDEEM_WATCH_CONTROL"]
    if Path(hook_setting("config", SYSTEM_CONFIG, env)).exists():
        return hook_settings(env).control
    return default_endpoints()[1]


# --------------------------------------------------------------------------- logging and files
def _log(message: str, env: Mapping[str, str]) -> None:
    """One line to stderr and to syslog (``$HDEEM_WATCH_LOG_SOCKET``, default /dev/log)."""
    line = f"{SYSLOG_TAG}: {message}"
    print(line, file=sys.stderr)
    address = env.get("HDEEM_WATCH_LOG_SOCKET") or "/dev/log"
    try:
        handler = logging.handlers.SysLogHandler(address=address, facility=logging.handlers.SysLogHandler.LOG_DAEMON)
    except OSError:
        return  # no syslog here: stderr is all there is
    try:
        record = logging.LogRecord(SYSLOG_TAG, logging.ERROR, __file__, 0,
                                   f"{SYSLOG_TAG}: {message}", None, None)
        handler.emit(record)
    finally:
        handler.close()


def _private_dir(path: Path) -> Path:
    path.mkdir(parents=True, exist_ok=True, mode=0o700)
    return path


def _private_file(path: Path, mode: str = "w") -> IO[str]:
    """``open(path, mode)`` of a file created 0600 whatever the umask (slurmd's is usually 022)."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_CLOEXEC | (os.O_APPEND if mode.startswith("a") else os.O_TRUNC)
    return os.fdopen(os.open(path, flags, 0o600), mode, encoding="utf-8")


def _write_private(path: Path, text: str) -> None:
    with _private_file(path) as out:
        out.write(text)


def _rotate(path: Path) -> None:
    """Beyond :data:`MAX_LOG_BYTES` the file becomes ``<name>.1`` (the one before it goes)."""
    with contextlib.suppress(OSError):
        if path.stat().st_size > MAX_LOG_BYTES:
            os.replace(path, path.with_name(path.name + ".1"))


def _append_bounded(path: Path, record: Mapping[str, Any]) -> None:
    """Append one JSON line (to a file kept below :data:`MAX_LOG_BYTES`, :func:`_rotate`)."""
    _rotate(path)
    with _private_file(path, "a") as out:
        out.write(json.dumps(record) + "\n")


# --------------------------------------------------------------------------- the daemon
def _call(control: str, op: str, args: dict[str, Any] | None, timeout_s: float) -> tuple[Any, str | None]:
    """``(result, None)`` or ``(None, why)``; never raises for an absent or refusing daemon."""
    from hdeem_watch.wire.client import ControlClient, ControlError, DaemonUnreachable

    with ControlClient(control, timeout_s=timeout_s) as client:
        try:
            return client.call(op, args), None
        except DaemonUnreachable as error:
            return None, f"unreachable: {error}"
        except ControlError as error:
            return None, str(error)


def _cpus(env: Mapping[str, str]) -> int | None:
    """The job's CPUs on this node (``SLURM_JOB_CPUS_PER_NODE``: ``4`` or ``4(x2),2``: the first)."""
    raw = env.get("SLURM_JOB_CPUS_PER_NODE", "")
    head = raw.split(",")[0].split("(")[0]
    return int(head) if head.isdigit() else None


def _start_daemon(s: HookSettings, job_id: str) -> str:
    """Start a daemon with the daemon's own config; return ``started`` or why not."""
    if s.source == "hdeem" and not s.start_hdeem:
        return "not started: its source is hdeem and HDEEM_WATCH_START_HDEEM is not 1"
    command = [sys.executable, "-m", "hdeem_watch", "daemon"]
    command += ["--config", s.config] if s.config else ["--pub", s.pub, "--control", s.control,
                                                         "--state-dir", str(s.state_dir)]
    log_path = s.hook_dir / "daemon.log"
    _rotate(log_path)
    with os.fdopen(os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_APPEND | os.O_CLOEXEC, 0o600), "ab") as out:
        proc = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=out, stderr=out, start_new_session=True,
                                close_fds=True, env=_daemon_env())
    deadline = time.monotonic() + s.start_timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            return f"not started: it exited with {proc.returncode} (see {log_path})"
        if _call(s.control, "ping", None, 0.5)[1] is None:
            _write_private(s.hook_dir / "daemon.json", json.dumps({"pid": proc.pid, "job_id": job_id,
                                                                    "command": command}))
            return "started"
        time.sleep(0.1)
    return f"started (pid {proc.pid}) but it did not answer within {s.start_timeout_s:g} s"


def _daemon_env() -> dict[str, str]:
    """The started daemon's environment: no SLURM job and no HDEEM_WATCH_* variables (the config
    file alone says where it listens, as it does for the hooks)."""
    return {k: v for k, v in os.environ.items() if not k.startswith(("SLURM", "HDEEM_WATCH_"))}


def _flush_pending_stops(s: HookSettings) -> None:
    """Send the stops a daemon missed (with the time each job ended)."""
    pending = sorted(s.hook_dir.glob("stop-*.json"), key=lambda p: p.stat().st_mtime)
    if not pending or _call(s.control, "ping", None, min(2.0, s.timeout_s))[1] is not None:
        return  # nothing to send, or the daemon is still down: keep them
    for stale in pending[:-MAX_PENDING_STOPS]:
        stale.unlink(missing_ok=True)
    for path in pending[-MAX_PENDING_STOPS:]:
        try:
            args = json.loads(path.read_text())
        except (OSError, ValueError):
            path.unlink(missing_ok=True)
            continue
        _result, why = _call(s.control, "job.stop", args, s.timeout_s)
        if why is not None and why.startswith("unreachable"):
            return  # still down: keep them all
        path.unlink(missing_ok=True)


# --------------------------------------------------------------------------- the hooks
def prolog(env: Mapping[str, str] | None = None) -> dict[str, Any]:
    """Open the job's window in this node's daemon (see the module docstring); return what was done.

    Without a job id (``SLURM_JOB_ID`` empty or unset) nothing is opened: :func:`_no_job_id`."""
    env, s, ctx, job_id = _begin(env)
    if job_id is None:
        return _no_job_id("prolog", env, ctx)
    record: dict[str, Any] = {"event": "prolog", "job_id": job_id, "user": ctx.get("user"), "node": ctx.get("node"),
                              "t_ns": time.time_ns(), "control": s.control, "daemon": "running"}
    if _call(s.control, "ping", None, min(2.0, s.timeout_s))[1] is not None:
        record["daemon"] = _start_daemon(s, job_id) if s.start_daemon else "none"
        if record["daemon"] != "started":
            _log(f"prolog job {job_id}: no daemon answers on {s.control}; the job is not measured "
                 f"(daemon: {record['daemon']})", env)
            _write_job(s, job_id, record)
            return record
    if s.baseline_s > 0:
        _result, why = _call(s.control, "baseline.measure", {"seconds": s.baseline_s}, s.baseline_s + s.timeout_s)
        record["baseline"] = "measured" if why is None else why
    uid = ctx.get("uid", "")
    args = {"job_id": job_id, "user": ctx.get("user", ""), "uid": int(uid) if uid.isdigit() else None,
            "nodes": ctx.get("nodelist", ""), "cpus": _cpus(env)}  # the hostlist as SLURM gives it (compact)
    _result, why = _call(s.control, "job.start", args, s.timeout_s)
    record["job_start"] = "ok" if why is None else why
    if why is not None:
        _log(f"prolog job {job_id}: job.start failed: {why}", env)
    _write_job(s, job_id, record)
    return record


def _begin(env: Mapping[str, str] | None) -> tuple[Mapping[str, str], HookSettings, dict[str, str], str | None]:
    """What both hooks do first: read their settings and the job, make the hooks' directory, and
    send the stops a daemon missed; ``(env, settings, job context, job id or None)``."""
    env = os.environ if env is None else env
    s = hook_settings(env)
    ctx = hook_context(env)
    _private_dir(s.hook_dir)
    _flush_pending_stops(s)
    return env, s, ctx, _job_id(ctx)


def _job_id(ctx: Mapping[str, str]) -> str | None:
    """The job's id when it is one the daemon takes (a SLURM job id), else None."""
    from hdeem_watch.wire.protocol import ProtocolError
    from hdeem_watch.wire.requests import job_id_arg

    try:
        return job_id_arg(ctx.get("job_id", "").strip(), "SLURM_JOB_ID")
    except ProtocolError:
        return None


def _no_job_id(event: str, env: Mapping[str, str], ctx: Mapping[str, str]) -> dict[str, Any]:
    """A hook without a usable job id: nothing is opened or closed (jobs must not share a made-up
    id, nor name files after a 100 KB one); say why."""
    from hdeem_watch.wire.protocol import quoted

    raw = ctx.get("job_id", "").strip()
    why = (f"SLURM_JOB_ID = {quoted(raw, 80)} is not a SLURM job id" if raw else "SLURM_JOB_ID is empty or unset")
    why += ": no job window opened or closed"
    _log(f"{event}: {why} (user {quoted(ctx.get('user', '?'), 80)}, node {quoted(ctx.get('node', '?'), 80)})", env)
    return {"event": event, "job_id": None, "skipped": why, "t_ns": time.time_ns()}


def _write_job(s: HookSettings, job_id: str, record: dict[str, Any]) -> None:
    _write_private(s.hook_dir / f"job-{job_id}.json", json.dumps(record))
    _append_bounded(s.hook_dir / "jobs.jsonl", record)


def epilog(env: Mapping[str, str] | None = None) -> dict[str, Any]:
    """Close the job's window in this node's daemon; return what was done (nothing without a job id)."""
    env, s, ctx, job_id = _begin(env)
    if job_id is None:
        return _no_job_id("epilog", env, ctx)
    exit_code = ctx.get("exit_code")
    # The job's end goes along: a stop the daemon reads late (it hung; the request waited in its
    # socket) is then marked late instead of silently measuring past the end.
    args: dict[str, Any] = {"job_id": job_id, "exit_code": exit_code, "ended_ns": time.time_ns()}
    try:
        started = json.loads((s.hook_dir / f"job-{job_id}.json").read_text()).get("job_start") == "ok"
    except (OSError, ValueError, AttributeError):
        started = True  # no Prolog record (the Prolog failed, or the hooks were installed mid-job): try
    result, why = _call(s.control, "job.stop", args, s.timeout_s) if started else (None, "skipped: not started")
    record: dict[str, Any] = {"event": "epilog", "job_id": job_id, "user": ctx.get("user"), "node": ctx.get("node"),
                              "t_ns": time.time_ns(), "exit_code": exit_code, "job_stop": "ok" if why is None else why}
    if why is not None and why.startswith("unreachable"):
        _write_private(s.hook_dir / f"stop-{job_id}.json", json.dumps(args))
        _log(f"epilog job {job_id}: {why}; the stop is kept and sent by the next hook", env)
    elif isinstance(result, dict):
        try:
            job = JobRecord.from_dict(result)
        except ValueError as error:
            record["job_stop"] = f"unreadable reply: {error}"
        else:
            record["dram_energy_j"] = job.dram_energy_j if math.isfinite(job.dram_energy_j) else None
            record["state"] = job.state
    record["daemon"] = _stop_started_daemon(s)
    (s.hook_dir / f"job-{job_id}.json").unlink(missing_ok=True)
    _append_bounded(s.hook_dir / "jobs.jsonl", record)
    return record


def _stop_started_daemon(s: HookSettings) -> str:
    """Stop the daemon the hooks started once no job is open on it; say what happened."""
    path = s.hook_dir / "daemon.json"
    try:
        pid = int(json.loads(path.read_text())["pid"])
    except (OSError, ValueError, KeyError, TypeError):
        return "not started by the hooks"
    status, why = _call(s.control, "status", None, s.timeout_s)
    if why is None and isinstance(status, dict) and status.get("jobs"):
        return f"kept: {len(status['jobs'])} jobs open"
    _stop_pid(pid)
    path.unlink(missing_ok=True)
    return "stopped"


def _stop_pid(pid: int, timeout_s: float = 10.0) -> None:
    """SIGTERM, then SIGKILL after ``timeout_s``."""
    try:
        os.kill(pid, signal.SIGTERM)
    except ProcessLookupError:
        return
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with contextlib.suppress(ChildProcessError):
            if os.waitpid(pid, os.WNOHANG)[0] == pid:
                return
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return
        time.sleep(0.05)
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, signal.SIGKILL)


def main(argv: Sequence[str] | None = None) -> int:
    """``python3 -m hdeem_watch.slurm prolog|epilog|nodes``: the hooks exit 0 whatever happens
    (failures are logged to syslog); 2 for a wrong action."""
    args = list(sys.argv[1:] if argv is None else argv)
    action = args[0] if args else ""
    if action == "nodes":
        print("\n".join(allocation_nodes()))
        return 0
    if action not in ("prolog", "epilog"):
        print("usage: python3 -m hdeem_watch.slurm prolog|epilog|nodes", file=sys.stderr)
        return 2
    try:
        record = prolog() if action == "prolog" else epilog()
        print(f"{SYSLOG_TAG}: {action} job {record.get('job_id')}: {json.dumps(record)}", file=sys.stderr)
    except Exception as error:  # never fail the hook; say why
        _log(f"{action} job {os.environ.get('SLURM_JOB_ID', '?')} failed: {type(error).__name__}: {error}",
             os.environ)
    return 0
