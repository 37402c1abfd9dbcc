"""``hdeem-watch completion bash|zsh``: scripts generated from the parser (issue 28)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from hdeem_watch.cli import SUBCOMMAND_MODULES
from hdeem_watch.cli.completion import script

SRC = Path(__file__).resolve().parents[1] / "src"


def test_both_scripts_name_every_subcommand_and_the_new_flags() -> None:
    """Generated from the parser: every subcommand, and flags added in this version (bench's
    --seconds, run stop's --abort) are in both scripts."""
    for shell in ("bash", "zsh"):
        text = script(shell)
        for module in SUBCOMMAND_MODULES:
            assert module.replace("_", "-") in text, (shell, module)
        assert "--seconds" in text and "--abort" in text


@pytest.mark.slow
def test_bash_completes_subcommands_and_flags(tmp_path: Path) -> None:
    """A real bash sources the script and completes `hdeem-watch ru` → run, `run st` → stop and
    `bench --sec` → --seconds."""
    completion = tmp_path / "hdeem-watch.bash"
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    made = subprocess.run([sys.executable, "-m", "hdeem_watch", "completion", "bash"], capture_output=True,
                          text=True, timeout=60, env=env, check=True)
    completion.write_text(made.stdout)
    probe = f"""
source {completion}
complete_words() {{ COMP_WORDS=("$@"); COMP_CWORD=$(( ${{#COMP_WORDS[@]}} - 1 )); COMP_LINE="$*"
  COMP_POINT=${{#COMP_LINE}}; COMPREPLY=(); _shtab_hdeem_watch; echo "${{COMPREPLY[*]}}"; }}
complete_words hdeem-watch ru
complete_words hdeem-watch run st
complete_words hdeem-watch bench --sec
"""
    out = subprocess.run(["bash", "-c", probe], capture_output=True, text=True, timeout=30, check=True).stdout
    assert out.splitlines() == ["run", "stop", "--seconds"], out


def _parsers(parser, name="hdeem-watch"):
    import argparse

    yield name, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            seen = set()
            for sub_name, sub in action.choices.items():
                if id(sub) not in seen:
                    seen.add(id(sub))
                    yield from _parsers(sub, f"{name} {sub_name}")


def test_every_help_text_fits_80_columns(monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 28: `demo --help` had 157-character lines, `tui --help` 126 (even in an 80-column
    terminal); every command's help is now at most 80 columns, and the tui's names the g key."""
    from hdeem_watch.cli import build_parser

    monkeypatch.setenv("COLUMNS", "200")  # a wide terminal still gets 80-column help
    helps = {name: parser.format_help() for name, parser in _parsers(build_parser())}
    assert len(helps) > 15
    for name, text in helps.items():
        assert max(len(line) for line in text.splitlines()) <= 80, name
    assert "g per-pair calibration" in helps["hdeem-watch tui"]


def test_every_flag_in_the_readmes_command_table_exists() -> None:
    """Issue 28: README's calib row promised `export --json`, which export does not have. Each
    command cell of README's table names only flags its (sub)command's parser has."""
    import re

    from hdeem_watch.cli import build_parser

    parsers = dict(_parsers(build_parser()))
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    checked = 0
    for row in re.findall(r"^\| (`hdeem-watch .*?) \| ", readme, flags=re.M):
        top = ""
        for cell in re.findall(r"`([^`]*)`", row):
            words = cell.replace("\\|", "|").split()
            if words[0] == "hdeem-watch":
                words, top = words[1:], words[1]
            elif not words[0].startswith("-"):  # `calib reset ...` after `hdeem-watch calib show ...`
                top = words[0]
            else:  # `--config FILE`: the row's command again
                words = [top, *words]
            names = ["hdeem-watch"]
            for word in words:
                longer = [f"{n} {w}" for n in names for w in word.split("|") if f"{n} {w}" in parsers]
                if not longer:
                    break
                names = longer
            for name in names:
                known = {o for a in parsers[name]._actions for o in a.option_strings}
                for flag in re.findall(r"(--[a-z][a-z-]*)", cell):
                    assert flag in known, (name, flag)
                checked += 1
    assert checked >= 15


def test_model_energy_tables_fit_80_columns(capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 28: `model energy`'s per-rank table was ~150 columns; commands and cycles per rank are
    two tables now, each row's numbers those of the JSON output."""
    import json

    from hdeem_watch.cli import main

    data = Path(__file__).resolve().parent / "data" / "drampower"
    args = ["model", "energy", "--memspec", str(data / "memspecs" / "ddr4_2133_x8_2r_1dev.json"),
            "--trace", str(data / "traces" / "idle_refresh.csv")]
    assert main(args) == 0
    text = capsys.readouterr().out
    assert max(len(line) for line in text.splitlines()) <= 80
    assert main([*args, "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    lines = text.splitlines()
    rank0 = lines[lines.index("commands per rank") + 2].split()
    assert [float(v) for v in rank0[1:]] == [float(v) for v in record["counts"][0].values()]
