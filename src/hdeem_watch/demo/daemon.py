"""The demo's daemon: a sim-source ``hdeem-watch daemon`` subprocess on private ipc endpoints.

:class:`DemoDaemon` creates a temporary runtime directory, starts ``python -m hdeem_watch daemon
--source sim`` with its PUB and control sockets there, waits until it answers ``status``, and on
exit (normal, exception or Ctrl-C) terminates it (SIGTERM, then SIGKILL) and removes the directory.

When the demo itself dies without cleaning up (``kill -9``), the daemon does not stay behind: on
Linux it is started with ``PR_SET_PDEATHSIG`` = SIGTERM (the kernel signals it when its parent
dies), and the next demo removes runtime directories whose owner process is gone (each holds an
``owner.pid``). The daemon's log is kept only with a ``state_dir`` (``<state_dir>/daemon.log``);
otherwise it lives and goes with the temporary directory.

Example:
    >>> with DemoDaemon() as daemon:  # doctest: +SKIP
    ...     daemon.control_endpoint
    'ipc:///tmp/hdeem-watch-demo-.../control.sock'
"""

from __future__ import annotations

import ctypes
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from types import TracebackType

from hdeem_watch.wire.client import ControlClient, ControlError, DaemonUnreachable

#: Prefix of the demo's temporary runtime directories.
RUNTIME_PREFIX = "hdeem-watch-demo-"
#: ``prctl`` option: the signal a process gets when its parent dies (linux/prctl.h).
PR_SET_PDEATHSIG = 1


def die_with_parent() -> Callable[[], None] | None:
    """A ``preexec_fn`` that makes the child get SIGTERM when its parent dies (Linux), else None.

    ``prctl`` is looked up here, in the parent, so the child only makes the call between fork and
    exec. The child also checks that its parent did not die before the call took effect.
    """
    if not sys.platform.startswith("linux"):
        return None
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    parent = os.getpid()

    def preexec() -> None:
        prctl(PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
        if os.getppid() != parent:  # the parent died before the call: act as if the signal came
            os.kill(os.getpid(), signal.SIGTERM)

    return preexec


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def sweep_orphaned_runtime_dirs(root: str | os.PathLike[str] | None = None) -> list[Path]:
    """Remove this user's demo runtime directories whose owner process is gone; return them.

    A directory without a readable ``owner.pid`` is left alone (it may be starting up).
    """
    removed = []
    for path in Path(root or tempfile.gettempdir()).glob(RUNTIME_PREFIX + "*"):
        try:
            if not path.is_dir() or path.stat().st_uid != os.getuid():
                continue
            pid = int((path / "owner.pid").read_text().strip())
        except (OSError, ValueError):
            continue
        if not _alive(pid):
            shutil.rmtree(path, ignore_errors=True)
            removed.append(path)
    return removed


class DaemonFailed(RuntimeError):
    """The demo daemon did not start (the message ends with its log's last lines)."""


class DemoDaemon:
    """A sim-source daemon subprocess with a temporary runtime directory.

    Args:
        state_dir: where its SQLite state goes (default: inside the temporary directory).
        node: node name.
        speed: time factor of the simulated node.
        start_timeout_s: how long to wait for the first ``status`` reply.
        extra_args: more daemon arguments.
    """

    def __init__(
        self,
        *,
        state_dir: str | os.PathLike[str] | None = None,
        node: str = "sim-node",
        speed: float = 1.0,
        start_timeout_s: float = 30.0,
        extra_args: tuple[str, ...] = (),
    ) -> None:
        sweep_orphaned_runtime_dirs()
        self.runtime_dir = Path(tempfile.mkdtemp(prefix=RUNTIME_PREFIX))
        (self.runtime_dir / "owner.pid").write_text(f"{os.getpid()}\n")
        self.state_dir = Path(state_dir) if state_dir is not None else self.runtime_dir / "state"
        #: whether the log outlives the demo (it does in a given state directory)
        self.log_kept = state_dir is not None
        self.node = node
        self.speed = speed
        self.start_timeout_s = start_timeout_s
        self.extra_args = extra_args
        self.pub_endpoint = f"ipc://{self.runtime_dir / 'pub.sock'}"
        self.control_endpoint = f"ipc://{self.runtime_dir / 'control.sock'}"
        self.log_path = (self.state_dir if self.log_kept else self.runtime_dir) / "daemon.log"
        self.process: subprocess.Popen[bytes] | None = None

    def command(self) -> list[str]:
        """The daemon's command line."""
        return [
            sys.executable, "-m", "hdeem_watch", "daemon",
            "--source", "sim",
            "--node", self.node,
            "--pub", self.pub_endpoint,
            "--control", self.control_endpoint,
            "--state-dir", str(self.state_dir),
            "--speed", f"{self.speed:g}",
            *self.extra_args,
        ]  # fmt: skip

    def start(self) -> DemoDaemon:
        """Start the subprocess and wait until it answers.

        Raises:
            DaemonFailed: it exited or did not answer in time.
        """
        self.state_dir.mkdir(parents=True, exist_ok=True)
        with open(self.log_path, "ab") as log:
            # same process group: a hang-up of the terminal (or Ctrl-C outside the TUI) reaches it
            # too; and it gets SIGTERM when the demo dies without cleaning up (kill -9)
            self.process = subprocess.Popen(
                self.command(), stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                preexec_fn=die_with_parent(),
            )  # fmt: skip
        client = ControlClient(self.control_endpoint, timeout_s=1.0)
        deadline = time.monotonic() + self.start_timeout_s
        try:
            while time.monotonic() < deadline:
                if self.process.poll() is not None:
                    raise DaemonFailed(f"the sim daemon exited with code {self.process.returncode}: {self.log_tail()}")
                try:
                    client.call("status")
                    return self
                except (DaemonUnreachable, ControlError):
                    time.sleep(0.2)
        finally:
            client.close()
        self.stop()
        raise DaemonFailed(f"the sim daemon did not answer within {self.start_timeout_s:g} s: {self.log_tail()}")

    def log_tail(self, lines: int = 5) -> str:
        """The last lines of the daemon's output, joined with " | "."""
        try:
            text = self.log_path.read_text(errors="replace").strip().splitlines()
        except OSError:
            return "(no log)"
        return " | ".join(text[-lines:]) or "(empty log)"

    def stop(self, timeout_s: float = 5.0) -> None:
        """Terminate the subprocess (SIGTERM, then SIGKILL) and remove the temporary directory."""
        proc = self.process
        if proc is not None and proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout_s)
        self.process = None
        shutil.rmtree(self.runtime_dir, ignore_errors=True)

    def kill(self) -> None:
        """Kill the subprocess with SIGKILL (a crash), keeping the directory so it can start again."""
        proc = self.process
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait(10)
        self.process = None

    def __enter__(self) -> DemoDaemon:
        return self.start()

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()
