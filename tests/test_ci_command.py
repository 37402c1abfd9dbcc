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


def test_a_plain_pytest_runs_on_both_cores_and_the_test_command_on_two_workers_more() -> None:
    """pyproject's ``addopts`` spread the inner loop's plain ``python3 -m pytest -q -m "not slow"``
    over the machine's 2 cores (``-n 2``, its tests are computation: a third worker only costs a
    collection), with the README command's ``--dist``; the README command runs two workers more,
    because a third of its tests' time is spent waiting on the processes they start (daemons,
    brokers, SLURM, terminals), which the extra workers fill (at stop 40: 245-262 s on four
    workers against 278-280 s on three, 0 failures in 3 full runs each)."""
    words = shlex.split(readme_test_command())
    pyproject = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))
    addopts = shlex.split(pyproject["tool"]["pytest"]["ini_options"]["addopts"])
    assert addopts[addopts.index("--dist") + 1] == words[words.index("--dist") + 1], (addopts, words)
    assert int(addopts[addopts.index("-n") + 1]) == 2, addopts
    assert int(words[words.index("-n") + 1]) == 4, words
