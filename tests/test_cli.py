"""The command line's shared contract: exit codes and one-line errors."""

from __future__ import annotations

import subprocess
import sys

from hdeem_watch.cli import main


def test_unknown_subcommand_is_bad_input(capsys) -> None:
    """An unknown subcommand is a one-line error on stderr and exit code 2."""
    assert main(["no-such-command"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("hdeem-watch: error:")
    assert "\n" not in err


def test_console_script_runs_as_module() -> None:
    """``python -m hdeem_watch --version`` prints the version and exits 0."""
    done = subprocess.run([sys.executable, "-m", "hdeem_watch", "--version"], capture_output=True, text=True)
    assert done.returncode == 0
    assert done.stdout.startswith("hdeem-watch ")
