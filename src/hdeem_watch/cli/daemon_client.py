"""The connection options every command that asks one daemon shares (``run``, ``calib``), and one
line per failure.

``--connect EP`` is the daemon's control endpoint (default: this node's daemon, as the SLURM hooks
find it), ``--timeout S`` the reply timeout, ``--server-key``/``--client-key`` the CURVE keys for
``tcp://``. :func:`open_client` checks them before any socket is made, so ``--connect garbage`` is
a one-line bad-input error (exit 2), not a ZeroMQ traceback; :func:`reported` turns what the daemon
answers (no reply, a refusal) into one line on stderr and exit code 1.

Example::

    add_connect_arguments(parser)                   # in register()
    with reported("run"), open_client(args) as client:   # in the command
        client.call("status")
"""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
from collections.abc import Iterator
from typing import TYPE_CHECKING

from hdeem_watch.cli.curve_options import add_server_key_argument, client_kwargs, curve_keys
from hdeem_watch.errors import InputError

if TYPE_CHECKING:
    from hdeem_watch.wire.client import ControlClient

#: ZeroMQ transports a control endpoint may use.
TRANSPORTS = ("ipc://", "tcp://")


class Failed(Exception):
    """The daemon did not answer or refused; the message is the one line to print (exit 1)."""


def add_connect_arguments(parser: argparse.ArgumentParser, *, timeout_s: float = 10.0) -> None:
    """Add ``--connect``, ``--timeout``, ``--server-key`` and ``--client-key``."""
    parser.add_argument("--connect", metavar="EP",
                        help="the daemon's control endpoint, e.g. tcp://node7:5591 (default: this node's daemon)")
    parser.add_argument("--timeout", type=float, default=timeout_s, metavar="S",
                        help=f"reply timeout in seconds (default {timeout_s:g})")
    add_server_key_argument(parser)


def check_endpoint(endpoint: str) -> str:
    """Return ``endpoint`` if it is an ``ipc://`` or ``tcp://host:port`` endpoint.

    Example:
        >>> check_endpoint("tcp://node7:5591")
        'tcp://node7:5591'

    Raises:
        InputError: anything else, named as ``--connect``.
    """
    ok = endpoint.startswith(TRANSPORTS) and len(endpoint) > len("ipc://")
    if ok and endpoint.startswith("tcp://"):
        host, _, port = endpoint[len("tcp://"):].rpartition(":")
        ok = bool(host) and port.isdigit() and 0 < int(port) < 65536
    if not ok:
        raise InputError(f"--connect {endpoint!r}: expected a control endpoint such as tcp://node7:5591 "
                         "or ipc:///run/hdeem-watch/control.sock")
    return endpoint


def open_client(args: argparse.Namespace) -> ControlClient:
    """The control client of the parsed options.

    Raises:
        InputError: a bad endpoint, timeout or key.
    """
    from hdeem_watch.slurm.hooks import local_control_endpoint
    from hdeem_watch.wire.client import ControlClient

    timeout = args.timeout
    if not (math.isfinite(timeout) and timeout > 0):
        raise InputError(f"--timeout {timeout!r}: expected seconds > 0")
    endpoint = check_endpoint(args.connect) if args.connect else local_control_endpoint()
    return ControlClient(endpoint, timeout_s=timeout, **client_kwargs(curve_keys(args)))


@contextlib.contextmanager
def reported(command: str) -> Iterator[None]:
    """Turn the daemon's failures inside the block into one line on stderr and :class:`SystemExit`
    with code 1 (no reply, a refusal, a socket error)."""
    import zmq

    from hdeem_watch.wire.client import ControlError, DaemonUnreachable

    try:
        yield
    except DaemonUnreachable as error:
        _fail(command, f"no reply from the daemon ({error})")
    except ControlError as error:
        _fail(command, f"the daemon refused: {error}")
    except zmq.ZMQError as error:
        _fail(command, f"cannot reach the daemon: {error}")
    except Failed as error:
        _fail(command, str(error))


def _fail(command: str, message: str) -> None:
    print(f"hdeem-watch {command}: error: {message}", file=sys.stderr)
    raise SystemExit(1)
