"""``hdeem-watch tui``: not built yet (its issue is open)."""

from __future__ import annotations

import argparse
import sys
from typing import Any


def register(subparsers: Any) -> None:
    """Add the ``tui`` subcommand."""
    parser = subparsers.add_parser("tui", help="(not built yet)")
    parser.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    print("hdeem-watch tui: not built yet", file=sys.stderr)
    return 1
