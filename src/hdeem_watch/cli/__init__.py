"""The ``hdeem-watch`` command line (the contract is in docs/cli.md and DESIGN.md §7).

Each subcommand lives in its own module of this package and exposes
``register(subparsers) -> None``, which adds its parser and sets ``func`` (a callable taking the
parsed ``argparse.Namespace`` and returning the exit code).

Exit codes: 0 success, 2 bad input (one line on stderr), 1 anything else.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence
from typing import Any

from hdeem_watch import __version__
from hdeem_watch.errors import InputError

#: Subcommand modules, in the order ``--help`` lists them.
SUBCOMMAND_MODULES = ("demo", "daemon", "tui", "bench", "model", "calibrate", "calib", "report", "node", "counters",
                      "metricq_source", "jobs", "run", "completion")

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130

#: The top-level help's closing text: one example per subcommand, and the exit codes.
EPILOG = """examples (COMMAND --help for each command's options and examples):
  hdeem-watch demo                         # simulated node, daemon and live TUI
  hdeem-watch daemon --source sim          # a node daemon (here the simulated node)
  hdeem-watch tui --connect tcp://node7:5591          # watch one or more daemons
  hdeem-watch bench --kernels triad --threads 1,4     # kernels (--daemon EP: runs)
  hdeem-watch run list                     # a daemon's runs (run stop --abort)
  hdeem-watch model energy --memspec ddr4-2133-x8-4gb --trace T.csv
  hdeem-watch calibrate --runs RUNS.json   # fit the currents to measured runs
  hdeem-watch calib show --json            # a running daemon's node and pair fits
  hdeem-watch report --runs RUNS.json --out DIR       # the paper's figures, HTML
  hdeem-watch node --json                  # sockets, channels, DIMMs, memspec
  hdeem-watch counters                     # this host's memory-controller counters
  hdeem-watch metricq-source --server amqp://HOST/    # the stream to MetricQ
  hdeem-watch jobs --job $SLURM_JOB_ID     # a SLURM job's DRAM energy per node
  hdeem-watch completion bash              # shell completion (bash or zsh)

exit codes: 0 success, 1 failure (one line on stderr), 2 bad input (one line on
  stderr), 130 interrupted (Ctrl-C)"""


#: The widest a help text may be (a terminal's default).
HELP_COLUMNS = 80


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Help in at most 80 columns: descriptions and epilogs keep their line breaks (examples stay
    one per line) but a line too long is wrapped, its continuation indented under it."""

    def __init__(self, prog: str, **kwargs: Any) -> None:
        import shutil

        kwargs["width"] = min(HELP_COLUMNS, shutil.get_terminal_size((HELP_COLUMNS, 24)).columns) - 1
        super().__init__(prog, **kwargs)

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        import textwrap

        lines = []
        for line in text.splitlines():
            lead = " " * (len(line) - len(line.lstrip()))
            if len(indent + line) <= width:
                lines.append(indent + line)
                continue
            more = lead + "    " if lead else ""
            lines.extend(textwrap.wrap(line, width, initial_indent=indent, subsequent_indent=indent + more,
                                       break_on_hyphens=False))
        return "\n".join(lines)


class _ArgumentParser(argparse.ArgumentParser):
    """An argparse parser whose usage errors are one line and exit code 2, and whose help fits 80
    columns (:class:`HelpFormatter`, whatever formatter a subcommand asks for)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs["formatter_class"] = HelpFormatter
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> None:  # type: ignore[override]
        command = self.prog.removeprefix("hdeem-watch").strip()  # main() says "hdeem-watch: error:" once
        raise InputError(f"{command}: {message}" if command else message)


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """Build the top-level parser.

    Args:
        only: register just this subcommand (the one being run), so that running one command does
            not import every other command's dependencies (scipy, textual, zmq); ``None`` registers
            all of them (``--help``).
    """
    parser = _ArgumentParser(
        prog="hdeem-watch",
        description="DRAM power monitoring and DRAM power-model calibration on HPC nodes.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"hdeem-watch {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_ArgumentParser)
    for name in SUBCOMMAND_MODULES if only is None else (only,):
        module = importlib.import_module(f"hdeem_watch.cli.{name}")
        module.register(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the exit code (also used as the console-script entry point)."""
    try:
        arguments = list(sys.argv[1:] if argv is None else argv)
        first = next((a for a in arguments if not a.startswith("-")), None)
        module = first.replace("-", "_") if first else None  # metricq-source lives in metricq_source.py
        parser = build_parser(module if module in SUBCOMMAND_MODULES else None)
        args = parser.parse_args(arguments)
        if getattr(args, "func", None) is None:
            parser.print_help(sys.stderr)
            return EXIT_BAD_INPUT
        return int(args.func(args) or 0)
    except InputError as error:
        print(f"hdeem-watch: error: {error}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        return EXIT_OK


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
