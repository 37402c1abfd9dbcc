"""CI runs exactly the README's test command, and that command keeps the SLURM tests on one worker."""

from __future__ import annotations

import re
import shlex
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def readme_test_command() -> str:
    """The command the README names as *the test command itself*."""
    text = (REPO / "README.md").read_text(encoding="utf-8")
    found = re.search(r"then the test command itself: `([^`]+)`", text)
    assert found, "README.md no longer names its test command ('then the test command itself: `...`')"
    return found.group(1)


def test_ci_runs_the_readmes_test_command_last() -> None:
    """The last command of .ci/run is the README's test command, word for word."""
    lines = [line.strip() for line in (REPO / ".ci" / "run").read_text(encoding="utf-8").splitlines()]
    commands = [line for line in lines if line and not line.startswith("#")]
    assert shlex.split(commands[-1]) == shlex.split(readme_test_command())


def test_the_test_command_groups_tests_that_share_a_machine_wide_resource() -> None:
    """The command runs on workers (``-n``) distributed by group (``--dist loadgroup``), so the
    tests marked ``xdist_group("slurm")`` (one munged, one cluster at a time) share one worker."""
    words = shlex.split(readme_test_command())
    assert "-n" in words and words[words.index("--dist") + 1] == "loadgroup", words


def test_a_plain_pytest_runs_on_the_workers_of_the_test_command() -> None:
    """pyproject's ``addopts`` carry the README command's ``-n`` and ``--dist``, so the inner loop's plain
    ``python3 -m pytest -q -m "not slow"`` is spread over the same workers as CI's run."""
    words = shlex.split(readme_test_command())
    pyproject = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))
    addopts = shlex.split(pyproject["tool"]["pytest"]["ini_options"]["addopts"])
    for option in ("-n", "--dist"):
        assert option in addopts, addopts
        assert addopts[addopts.index(option) + 1] == words[words.index(option) + 1], (option, addopts, words)
