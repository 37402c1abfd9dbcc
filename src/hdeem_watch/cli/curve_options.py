"""The ``--server-key`` / ``--client-key`` options every client command shares (``tui``, ``bench``,
``jobs``), and their resolution into CURVE keys.

Example::

    from hdeem_watch.cli.curve_options import add_server_key_argument, curve_keys
    add_server_key_argument(parser)            # in register()
    curve = curve_keys(args)                   # in the command: ClientCurve or None
    ControlClient(endpoint, **client_kwargs(curve))
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from hdeem_watch.wire.keys import ClientCurve

# The names of hdeem_watch.wire.keys's SERVER_KEY_ENV, CLIENT_KEY_ENV and DEFAULT_CONFIG
# (spelt out so that registering the options does not load ZeroMQ; a test keeps them equal).
SERVER_KEY_ENV = "HDEEM_WATCH_SERVER_KEY"
CLIENT_KEY_ENV = "HDEEM_WATCH_CLIENT_KEY"
DEFAULT_CONFIG = "/etc/hdeem-watch/hdeem-watchd.toml"


def add_server_key_argument(parser: argparse.ArgumentParser) -> None:
    """Add ``--server-key FILE`` and ``--client-key FILE`` to a client command."""
    parser.add_argument("--server-key", metavar="FILE", default=None,
                        help="the daemon's CURVE public key (server.key) for tcp:// endpoints (default "
                        f"${SERVER_KEY_ENV}, else curve_public_key_file of {DEFAULT_CONFIG})")
    parser.add_argument("--client-key", metavar="FILE", default=None,
                        help="this client's CURVE key pair (.key_secret) registered with the daemon, needed to "
                        f"start runs over TCP (default ${CLIENT_KEY_ENV}, else "
                        "~/.config/hdeem-watch/client.key_secret if it exists, else a one-off pair)")


def curve_keys(args: argparse.Namespace) -> ClientCurve | None:
    """The CURVE keys of the parsed options (None: no CURVE).

    Raises:
        InputError: a key named by an option or variable cannot be read.
    """
    from hdeem_watch.wire.keys import client_curve

    return client_curve(getattr(args, "server_key", None), getattr(args, "client_key", None))


def client_kwargs(curve: ClientCurve | None) -> dict[str, Any]:
    """Keyword arguments of :class:`~hdeem_watch.wire.client.ControlClient` for ``curve``."""
    if curve is None:
        return {}
    return {"curve_server_key": curve.server_key, "curve_client_keys": curve.client_keys}
