"""The command line's shared contract: exit codes and one-line errors."""

from __future__ import annotations

import subprocess
import sys

import pytest

from hdeem_watch.cli import main


def test_unknown_subcommand_is_bad_input(capsys) -> None:
    """An unknown subcommand is a one-line error on stderr and exit code 2."""
    assert main(["no-such-command"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("hdeem-watch: error:")
    assert "\n" not in err


@pytest.mark.slow
def test_console_script_runs_as_module() -> None:
    """``python -m hdeem_watch --version`` prints the version and exits 0."""
    done = subprocess.run([sys.executable, "-m", "hdeem_watch", "--version"], capture_output=True, text=True)
    assert done.returncode == 0
    assert done.stdout.startswith("hdeem-watch ")


def test_top_level_help_has_an_example_per_subcommand_and_the_exit_codes(capsys) -> None:
    """``hdeem-watch --help`` shows one example line for every subcommand and what each exit code means."""
    from hdeem_watch.cli import SUBCOMMAND_MODULES

    try:
        main(["--help"])
    except SystemExit as done:
        assert done.code == 0
    out = capsys.readouterr().out
    examples = [line.split() for line in out.splitlines() if line.strip().startswith("hdeem-watch ")]
    assert {words[1].replace("-", "_") for words in examples} == set(SUBCOMMAND_MODULES)
    for code in ("0 success", "1 failure", "2 bad input", "130 interrupted"):
        assert code in out, code


def test_tui_and_demo_help_state_defaults_examples_and_exit_codes(capsys) -> None:
    """tui/demo --help give the defaults of --fps and --window (and why the demo's window is 30 s),
    examples and exit codes."""
    texts = {}
    for command in ("tui", "demo"):
        try:
            main([command, "--help"])
        except SystemExit as done:
            assert done.code == 0
        texts[command] = " ".join(capsys.readouterr().out.split())
    assert "default 10" in texts["tui"] and "default 60" in texts["tui"]
    assert "default 10" in texts["demo"] and "default 30" in texts["demo"] and "tui's 60" in texts["demo"]
    for text in texts.values():
        assert "examples:" in text and "exit codes:" in text and "2 bad input" in text
