"""``hdeem-watch model ...``: the DRAM model on its own (energy, command statistics, kernels).

The sub-subcommands live in their own modules: ``energy`` in :mod:`hdeem_watch.cli.model_energy`,
``stats`` and ``kernel`` in :mod:`hdeem_watch.cli.model_stats`.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from hdeem_watch.cli import model_energy, model_stats

#: Exit code of ``hdeem-watch model`` without a sub-subcommand (bad input, as at the top level).
EXIT_USAGE = 2


def register(subparsers: Any) -> None:
    """Add ``model`` and its sub-subcommands."""
    parser = subparsers.add_parser("model", help="DRAM model: energy of a trace, command statistics, kernels")
    model_subparsers = parser.add_subparsers(dest="model_command", metavar="MODEL_COMMAND",
                                             parser_class=type(parser))
    model_energy.register(model_subparsers)
    model_stats.register(model_subparsers)

    def usage(_args: argparse.Namespace) -> int:
        """``hdeem-watch model`` alone: ``model``'s own help (its sub-subcommands), not the top level's."""
        parser.print_help(sys.stderr)
        return EXIT_USAGE

    parser.set_defaults(func=usage)
