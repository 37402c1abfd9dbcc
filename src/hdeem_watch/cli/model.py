"""``hdeem-watch model``: not built yet (its issue is open)."""

from __future__ import annotations

import argparse
import sys
from typing import Any


def register(subparsers: Any) -> None:
    """Add the ``model`` subcommand."""
    parser = subparsers.add_parser("model", help="(not built yet)")
    parser.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    print("hdeem-watch model: not built yet", file=sys.stderr)
    return 1
