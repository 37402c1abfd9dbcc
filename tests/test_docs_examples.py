"""Every ``hdeem-watch`` command shown in README.md, docs/*.md and examples/README.md runs as written.

A command is a line of a fenced code block that starts with ``hdeem-watch `` (lines ending in ``\\``
continue it). Blocks fenced as ```` ```text ```` are synopses (placeholders, ``[optional]`` parts)
and are not run. Each command runs through bash from the repository root, with ``hdeem-watch``
resolving to this checkout's code and private runtime and state directories. A command that runs
until it is stopped (the daemon, the TUI, the demo) must, once it has printed its first line, still be
running :data:`OBSERVE_S` later and exit 0 on Ctrl-C (SIGINT to its process group, as a terminal sends it); every other command must
exit 0 on its own. The TUI's commands get a simulated daemon on the default endpoint to watch.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from hdeem_watch.wire.client import ControlClient, DaemonUnreachable, default_endpoints

REPO = Path(__file__).resolve().parents[1]
DOCUMENTS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md")), REPO / "examples" / "README.md"]

#: Commands not run here, by prefix, each with the reason (keep this list short).
SKIP = {
    "hdeem-watch daemon --source hdeem": "needs HDEEM hardware (libhdeem on a Bull/Atos node)",
    "hdeem-watch daemon --config /etc/": "the node's installed configuration (source hdeem)",
    "hdeem-watch daemon --gen-keys /etc/": "writes server keys into /etc",
    "hdeem-watch daemon --pub tcp://0.0.0.0:": "fixed TCP ports and CURVE keys in /etc",
    "hdeem-watch tui --connect tcp://node7:": "needs the cluster nodes node7 and node8",
    "hdeem-watch tui --slurm": "needs a SLURM allocation",
    "hdeem-watch bench --kernels all+idle --threads 1,2 --daemon ipc:///run/": "the node's system daemon "
    "(the same command against a real sim daemon: tests/bench/test_daemon_announce.py)",
}
#: Commands that run until stopped: they must survive :data:`OBSERVE_S` past their first printed line
#: (the start-up log of the daemon, the demo's and the TUI's first lines; the interpreter's start
#: before it is not counted: 1 s on a quiet machine, several under load), then stop cleanly on SIGINT.
RUNS_UNTIL_STOPPED = ("hdeem-watch daemon", "hdeem-watch tui", "hdeem-watch demo")
OBSERVE_S = 2.0
#: The longest a command that runs until stopped may take to print its first line.
START_S = 60.0
#: Absolute example paths moved into the test's directory (parallel runs must not share sockets).
PRIVATE_PATHS = ("/tmp/hw/",)


def documented_commands() -> list[tuple[str, str]]:
    """``(where, command)`` for every command line of every fenced block except ```text ones."""
    found = []
    for path in DOCUMENTS:
        text = path.read_text(encoding="utf-8")
        for block in re.finditer(r"^```([^\n]*)\n(.*?)^```", text, re.S | re.M):
            if block.group(1).strip() == "text":
                continue
            first_line = text[:block.start()].count("\n") + 2
            lines = block.group(2).split("\n")
            i = 0
            while i < len(lines):
                start = i
                command = lines[i].strip()
                while command.endswith("\\") and i + 1 < len(lines):
                    i += 1
                    command = command[:-1].rstrip() + " " + lines[i].strip()
                if command.startswith("hdeem-watch "):
                    found.append((f"{path.relative_to(REPO)}:{first_line + start}", command))
                i += 1
    return found


COMMANDS = documented_commands()


def distinct_commands(commands: list[tuple[str, str]]) -> list[tuple[str, str]]:
    """``(places, command)`` once per distinct command, ``places`` listing every place that shows it
    (``README.md:70, docs/calibration.md:263``): a command documented in three places runs once."""
    places: dict[str, list[str]] = {}
    for where, command in commands:
        places.setdefault(command, []).append(where)
    return [(", ".join(wheres), command) for command, wheres in places.items()]


def _case(where: str, command: str) -> object:
    """One documented command as a test case, named after the first place that shows it."""
    return pytest.param(where, command, id=where.split(",")[0])


def test_the_documents_show_commands() -> None:
    """The collection finds the documented commands (the parametrized test cannot pass empty)."""
    assert len(COMMANDS) >= 15
    assert {where.split(":")[0] for where, _ in COMMANDS} >= {"README.md", "docs/daemon.md", "docs/tui.md"}


def test_a_command_shown_in_several_places_runs_once_naming_every_place() -> None:
    """The same command line in README.md and docs/ is one test case whose failure names both places."""
    cases = distinct_commands([("a.md:1", "hdeem-watch x"), ("b.md:5", "hdeem-watch y"), ("c.md:9", "hdeem-watch x")])
    assert cases == [("a.md:1, c.md:9", "hdeem-watch x"), ("b.md:5", "hdeem-watch y")]
    assert len(distinct_commands(COMMANDS)) < len(COMMANDS)  # README's quick start repeats docs/ commands


def test_every_skipped_command_is_still_documented() -> None:
    """Each skip-list entry matches a documented command (a stale entry would hide nothing)."""
    for prefix in SKIP:
        assert any(command.startswith(prefix) for _, command in COMMANDS), prefix


@pytest.fixture
def shell_env(tmp_path: Path) -> dict[str, str]:
    """Environment of a documented command: this checkout's ``hdeem-watch``, private directories."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    script = bin_dir / "hdeem-watch"
    script.write_text(f'#!/bin/sh\nexec "{sys.executable}" -m hdeem_watch "$@"\n')
    script.chmod(0o755)
    env = {k: v for k, v in os.environ.items() if not k.startswith(("SLURM_", "HDEEM_WATCH_"))}
    env.update({
        "PATH": f"{bin_dir}{os.pathsep}{env.get('PATH', '')}",
        "PYTHONPATH": f"{REPO / 'src'}{os.pathsep}{env.get('PYTHONPATH', '')}",
        "HDEEM_WATCH_RUNTIME_DIR": str(tmp_path / "run"),
        "XDG_RUNTIME_DIR": str(tmp_path / "xdg-run"),
        "XDG_STATE_HOME": str(tmp_path / "state"),
        "TERM": "dumb",
    })
    return env


@pytest.fixture
def local_daemon(shell_env: dict[str, str], tmp_path: Path) -> Iterator[None]:
    """A simulated daemon on the default endpoints of the command's runtime directory."""
    log = open(tmp_path / "daemon.log", "wb")  # noqa: SIM115 - closed below
    proc = subprocess.Popen([sys.executable, "-m", "hdeem_watch", "daemon", "--speed", "10", "--state-dir",
                             str(tmp_path / "daemon-state")], env=shell_env, stdout=log, stderr=subprocess.STDOUT)
    try:
        _, control = default_endpoints(shell_env["HDEEM_WATCH_RUNTIME_DIR"])
        deadline = time.monotonic() + 30
        with ControlClient(control, timeout_s=1.0) as client:
            while True:
                try:
                    client.call("status")
                    break
                except DaemonUnreachable:
                    assert proc.poll() is None and time.monotonic() < deadline, \
                        (tmp_path / "daemon.log").read_text()[-2000:]
                    time.sleep(0.1)
        yield
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        log.close()


def _first_line(proc: subprocess.Popen[bytes], *outputs: Path) -> bool:
    """Wait until the process has written a whole line to one of ``outputs`` or ended (True), or
    :data:`START_S` passed (False)."""
    deadline = time.monotonic() + START_S
    while time.monotonic() < deadline:
        if proc.poll() is not None or any(b"\n" in path.read_bytes() for path in outputs):
            return True
        time.sleep(0.05)
    return False


@pytest.mark.slow
@pytest.mark.parametrize(("where", "command"), [_case(where, command) for where, command in distinct_commands(COMMANDS)])
def test_documented_command_runs_as_written(where: str, command: str, shell_env: dict[str, str],
                                            tmp_path: Path, request: pytest.FixtureRequest) -> None:
    """The command exits 0 (or, if it runs until stopped, keeps running and stops cleanly on Ctrl-C)."""
    reason = next((why for prefix, why in SKIP.items() if command.startswith(prefix)), None)
    if reason is not None:
        pytest.skip(f"not run here: {reason}")
    if command.startswith("hdeem-watch tui"):
        request.getfixturevalue("local_daemon")
    runnable = command
    for path in PRIVATE_PATHS:
        runnable = runnable.replace(path, f"{tmp_path}{path}")
    # A working directory that sees the repository's files (examples/, tests/data/, …) through symlinks:
    # what a command writes by relative path (``--record rec.csv``) lands here, not in the clone.
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    for entry in REPO.iterdir():
        if not entry.name.startswith("."):
            (cwd / entry.name).symlink_to(entry)
    out_path, err_path = tmp_path / "stdout.txt", tmp_path / "stderr.txt"
    with open(out_path, "wb") as out_file, open(err_path, "wb") as err_file:
        proc = subprocess.Popen(["bash", "-c", runnable], cwd=cwd, env=shell_env, stdout=out_file,
                                stderr=err_file, start_new_session=True)
    try:
        expected: tuple[int, ...] = (0,)
        if command.startswith(RUNS_UNTIL_STOPPED):
            printed = _first_line(proc, out_path, err_path)
            assert printed, f"{where}: {command}\nprinted nothing in {START_S:g} s"
            try:
                proc.wait(timeout=OBSERVE_S)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGINT)
                proc.wait(timeout=60)
                # the daemon documents exit 0 after SIGINT; the TUI and the demo end as interrupted (130)
                expected = (0,) if command.startswith("hdeem-watch daemon") else (0, 130)
            else:
                assert proc.returncode == 0, f"{where}: {command}\nended early:\n{err_path.read_text()[-3000:]}"
        else:
            proc.wait(timeout=180)
            assert out_path.read_text().strip(), f"{where}: {command}\nprinted nothing\n{err_path.read_text()[-3000:]}"
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    err = err_path.read_text(errors="replace")
    assert proc.returncode in expected, f"{where}: {command}\nexit {proc.returncode}\n{err[-3000:]}"
    assert "Traceback" not in err, f"{where}: {command}\n{err[-3000:]}"
