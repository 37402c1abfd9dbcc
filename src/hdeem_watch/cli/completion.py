"""``hdeem-watch completion bash|zsh``: a shell completion script, generated from the argument
parser itself (with `shtab <https://github.com/iterative/shtab>`_), so it always knows every
subcommand and flag of this version.

Example::

    hdeem-watch completion bash > ~/.local/share/bash-completion/completions/hdeem-watch
    hdeem-watch completion zsh > ~/.zfunc/_hdeem-watch     # with fpath+=(~/.zfunc) in ~/.zshrc
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

SHELLS = ("bash", "zsh")


def register(subparsers: Any) -> None:
    """Add the ``completion`` subcommand."""
    parser = subparsers.add_parser(
        "completion", help="print a bash or zsh completion script",
        description="Print a shell completion script for hdeem-watch, generated from its argument parser.",
        epilog="examples:\n"
               "  hdeem-watch completion bash > ~/.local/share/bash-completion/completions/hdeem-watch\n"
               "  hdeem-watch completion zsh > ~/.zfunc/_hdeem-watch",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("shell", choices=SHELLS, help="the shell")
    parser.set_defaults(func=_run)


def script(shell: str) -> str:
    """The completion script of every subcommand for ``shell`` (``bash`` or ``zsh``)."""
    import shtab

    from hdeem_watch.cli import build_parser

    parser = build_parser()
    _drop_aliases(parser)
    return str(shtab.complete(parser, shell=shell))


def _drop_aliases(parser: argparse.ArgumentParser) -> None:
    """Complete each subcommand under its own name only (``metricq-source``, not its alias
    ``metricq_source``, which shtab's zsh script would list instead)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in list(action.choices.items()):
                if not sub.prog.endswith(" " + name):
                    del action.choices[name]
                _drop_aliases(sub)


def _run(args: argparse.Namespace) -> int:
    sys.stdout.write(script(args.shell))
    return 0
