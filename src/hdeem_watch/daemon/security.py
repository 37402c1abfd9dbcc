"""CURVE encryption and authentication of the daemon's sockets (for remote TCP subscribers).

ZeroMQ's CURVE gives every connection encryption and server authentication; with a directory of
allowed client public keys it also authenticates the clients. Keys are ZeroMQ certificate files
(``zmq.auth`` format): :func:`generate_keys` writes ``<name>.key`` (public) and
``<name>.key_secret`` (public + secret).

Daemon: ``curve_secret_key_file`` (its ``.key_secret``) makes both sockets CURVE servers;
``curve_clients_dir`` (a directory of clients' ``.key`` files) restricts who may connect (without it
any client that knows the server's public key may). Clients: :func:`secure_client` on any socket
(SUB, DEALER, REQ) with the server's public key; ``ControlClient(..., curve_server_key=...)`` does it
for control.

Example:
    >>> import tempfile, zmq
    >>> public, secret = generate_keys(tempfile.mkdtemp(), "server")
    >>> sock = zmq.Context.instance().socket(zmq.SUB)
    >>> secure_client(sock, load_public_key(public))
    >>> sock.close()
"""

from __future__ import annotations

import logging
import os
from collections.abc import MutableMapping
from pathlib import Path
from typing import Any

import zmq
import zmq.auth

from hdeem_watch.errors import InputError

log = logging.getLogger("hdeem_watch.daemon.security")


class RefusalLog(logging.LoggerAdapter):  # type: ignore[type-arg]
    """The ZAP authenticator's log with its refusals raised from DEBUG to WARNING.

    pyzmq's authenticator reports a refused client (``DENIED (CURVE) ... client_key=...``) only at
    DEBUG; a refusal is what an operator wants to see (a misconfigured client, or a probe).
    """

    def process(self, msg: Any, kwargs: MutableMapping[str, Any]) -> tuple[Any, MutableMapping[str, Any]]:
        return msg, kwargs

    def debug(self, msg: object, *args: object, **kwargs: Any) -> None:
        """DEBUG, or WARNING for a ``DENIED`` decision."""
        if isinstance(msg, str) and (msg.startswith("DENIED") or (msg.startswith("%s (") and args and args[0] == "DENIED")):
            self.logger.warning("CURVE: connection refused: " + msg, *args, **kwargs)
        else:
            self.logger.debug(msg, *args, **kwargs)


def generate_keys(directory: str | os.PathLike[str], name: str) -> tuple[Path, Path]:
    """Write a new key pair ``<name>.key`` / ``<name>.key_secret`` (secret file mode 0600)."""
    target = Path(directory)
    target.mkdir(parents=True, exist_ok=True, mode=0o750)
    public, secret = zmq.auth.create_certificates(target, name)
    os.chmod(secret, 0o600)
    return Path(public), Path(secret)


def load_public_key(path: str | os.PathLike[str]) -> bytes:
    """The public key of a certificate file (``.key`` or ``.key_secret``).

    Raises:
        InputError: unreadable or not a certificate.
    """
    try:
        public, _secret = zmq.auth.load_certificate(path)
    except (OSError, ValueError) as error:
        raise InputError(f"{path}: not a readable ZeroMQ certificate ({error})") from None
    return public


def load_secret_key(path: str | os.PathLike[str]) -> tuple[bytes, bytes]:
    """``(public, secret)`` of a ``.key_secret`` file.

    Raises:
        InputError: unreadable, or a public-only certificate.
    """
    try:
        public, secret = zmq.auth.load_certificate(path)
    except (OSError, ValueError) as error:
        raise InputError(f"{path}: not a readable ZeroMQ certificate ({error})") from None
    if not secret:
        raise InputError(f"{path}: has no secret key; expected the .key_secret file")
    return public, secret


def secure_server(sock: zmq.Socket[Any], public: bytes, secret: bytes) -> None:
    """Make ``sock`` a CURVE server (before it binds)."""
    sock.setsockopt(zmq.CURVE_PUBLICKEY, public)
    sock.setsockopt(zmq.CURVE_SECRETKEY, secret)
    sock.setsockopt(zmq.CURVE_SERVER, 1)


def secure_client(sock: zmq.Socket[Any], server_public: bytes, client_keys: tuple[bytes, bytes] | None = None) -> None:
    """Make ``sock`` a CURVE client of the server with ``server_public`` (before it connects).

    ``client_keys`` = ``(public, secret)`` of the client; default an ephemeral pair (enough when the
    daemon allows any client).
    """
    public, secret = client_keys if client_keys is not None else zmq.curve_keypair()
    sock.setsockopt(zmq.CURVE_SERVERKEY, server_public)
    sock.setsockopt(zmq.CURVE_PUBLICKEY, public)
    sock.setsockopt(zmq.CURVE_SECRETKEY, secret)


class CurveServer:
    """The daemon's CURVE setup: its key pair and the ZAP authenticator thread.

    Args:
        context: the daemon's ZeroMQ context.
        secret_key_file: the daemon's ``.key_secret``.
        clients_dir: directory of allowed clients' public ``.key`` files (None = any client).
    """

    def __init__(self, context: zmq.Context[Any], secret_key_file: str, clients_dir: str | None) -> None:
        from zmq.auth.thread import ThreadAuthenticator

        self.public, self.secret = load_secret_key(secret_key_file)
        if clients_dir is not None and not Path(clients_dir).is_dir():
            raise InputError(f"curve_clients_dir {clients_dir}: not a directory")
        self.authenticator = ThreadAuthenticator(context, log=RefusalLog(log, {}))
        self.authenticator.start()
        self.authenticator.configure_curve(domain="*", location=clients_dir or zmq.auth.CURVE_ALLOW_ANY)

    def apply(self, sock: zmq.Socket[Any]) -> None:
        """Make ``sock`` a CURVE server with the daemon's keys."""
        secure_server(sock, self.public, self.secret)

    def close(self) -> None:
        """Stop the authenticator thread."""
        self.authenticator.stop()
