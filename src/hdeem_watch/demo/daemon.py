"""The demo's daemon: a sim-source ``hdeem-watch daemon`` subprocess on private ipc endpoints.

:class:`DemoDaemon` creates a temporary runtime directory, starts ``python -m hdeem_watch daemon
--source sim`` with its PUB and control sockets there, waits until it answers ``status``, and on
exit (normal, exception or Ctrl-C) terminates it (SIGTERM, then SIGKILL) and removes the directory.

Example:
    >>> with DemoDaemon() as daemon:  # doctest: +SKIP
    ...     daemon.control_endpoint
    'ipc:///tmp/hdeem-watch-demo-.../control.sock'
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import TracebackType

from hdeem_watch.daemon.client import ControlClient, ControlError, DaemonUnreachable


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
        self.runtime_dir = Path(tempfile.mkdtemp(prefix="hdeem-watch-demo-"))
        self.state_dir = Path(state_dir) if state_dir is not None else self.runtime_dir / "state"
        self.node = node
        self.speed = speed
        self.start_timeout_s = start_timeout_s
        self.extra_args = extra_args
        self.pub_endpoint = f"ipc://{self.runtime_dir / 'pub.sock'}"
        self.control_endpoint = f"ipc://{self.runtime_dir / 'control.sock'}"
        self.log_path = self.runtime_dir / "daemon.log"
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
        with open(self.log_path, "wb") as log:
            # same process group: a hang-up of the terminal (or Ctrl-C outside the TUI) reaches it too
            self.process = subprocess.Popen(
                self.command(), stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
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
