"""The control port of the daemons that ``--slurm`` clients (``tui``, ``jobs``) ask on every node.

Example:
    >>> control_port(None, {}), control_port(None, {"HDEEM_WATCH_CONTROL_PORT": "7411"}), control_port(9, {})
    (5591, 7411, 9)
"""

from __future__ import annotations

from collections.abc import Mapping

from hdeem_watch.addresses import CONTROL_PORT
from hdeem_watch.errors import InputError

__all__ = ["CONTROL_PORT", "CONTROL_PORT_ENV", "control_port"]

#: The variable that names another control port than :data:`~hdeem_watch.addresses.CONTROL_PORT`.
CONTROL_PORT_ENV = "HDEEM_WATCH_CONTROL_PORT"


def control_port(port: int | None, env: Mapping[str, str]) -> int:
    """``port`` (``--port``), else ``$HDEEM_WATCH_CONTROL_PORT``, else :data:`CONTROL_PORT`.

    Raises:
        InputError: the variable is not a number, or the port is outside 1..65535.
    """
    if port is None:
        raw = env.get(CONTROL_PORT_ENV, str(CONTROL_PORT))
        try:
            port = int(raw)
        except ValueError:
            raise InputError(f"${CONTROL_PORT_ENV} = {raw!r}: expected a TCP port number") from None
    if not 0 < port < 65536:
        raise InputError(f"--port {port}: expected 1..65535")
    return port
