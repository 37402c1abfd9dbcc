"""CURVE encryption and authentication of the daemon's sockets (for remote TCP subscribers).

ZeroMQ's CURVE gives every connection encryption and server authentication; with a directory of
allowed client public keys it also authenticates the clients. Keys are ZeroMQ certificate files
(``zmq.auth`` format, written by :func:`hdeem_watch.wire.keys.generate_keys`).

Daemon: ``curve_secret_key_file`` (its ``.key_secret``) makes its TCP sockets CURVE servers;
``curve_clients_dir`` (a directory of clients' ``.key`` files) restricts who may connect (without it
any client that knows the server's public key may). A key file named ``<user>.key`` or
``<user>@<label>.key`` registers the key for that local user: the ZAP handler hands the user name
on as the connection's ``User-Id``, which authorizes state-changing requests
(:mod:`hdeem_watch.daemon.shell.authorization`). The client's side is :mod:`hdeem_watch.wire.keys`.

Example:
    >>> import tempfile, zmq
    >>> from hdeem_watch.wire.keys import generate_keys, load_secret_key
    >>> public, secret = generate_keys(tempfile.mkdtemp(), "server")
    >>> sock = zmq.Context.instance().socket(zmq.PUB)
    >>> secure_server(sock, *load_secret_key(secret))
    >>> sock.close()
"""

from __future__ import annotations

import logging
import os
import re
import stat
from collections.abc import Mapping, MutableMapping
from pathlib import Path
from typing import Any

import zmq
import zmq.auth
from zmq.utils import z85

from hdeem_watch.errors import InputError
from hdeem_watch.wire.keys import PUBLIC_KEY_MODE, load_secret_key

log = logging.getLogger("hdeem_watch.daemon.shell.security")


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


def secure_server(sock: zmq.Socket[Any], public: bytes, secret: bytes) -> None:
    """Make ``sock`` a CURVE server (before it binds)."""
    sock.setsockopt(zmq.CURVE_PUBLICKEY, public)
    sock.setsockopt(zmq.CURVE_SECRETKEY, secret)
    sock.setsockopt(zmq.CURVE_SERVER, 1)


_KEY_FILE_USER = re.compile(r"^([a-z_][a-z0-9_.-]{0,31})(?:@[^/]*)?\.key$")

#: The most each CURVE file may allow: the daemon's secret key owner-read (group-read for a daemon
#: user in root's group), the clients directory and its public keys writable by their owner only.
SECRET_KEY_MODE, CLIENTS_DIR_MODE, CLIENT_KEY_MODE = 0o640, 0o755, PUBLIC_KEY_MODE


def curve_file_problem(path: str | os.PathLike[str], most: int, *, directory: bool = False) -> str | None:
    """Why ``path`` may not be trusted as a CURVE file of this daemon, or None when it may.

    Trusted: owned by root or the daemon's user (the one who could replace it anyway) and mode at
    most ``most``: a clients directory another user may write lets them register their key for
    root; a secret key others may read lets them pose as the daemon.
    """
    try:
        st = os.stat(path)
    except OSError as error:
        return f"cannot be read ({error.strerror})"
    kind = "directory" if directory else "regular file"
    if (stat.S_ISDIR(st.st_mode) if directory else stat.S_ISREG(st.st_mode)) is False:
        return f"is not a {kind}"
    if st.st_uid not in (0, os.geteuid()):
        return f"is owned by uid {st.st_uid}, not by root or the daemon's user (uid {os.geteuid()})"
    if st.st_mode & 0o7777 & ~most:
        return f"has mode {st.st_mode & 0o7777:04o}; expected at most {most:04o}"
    return None


def _refuse(path: str | os.PathLike[str], what: str, problem: str | None) -> None:
    if problem is not None:
        raise InputError(f"{what} {path}: {problem}; refusing to start (fix its owner or mode: chmod go-w, "
                         "and go-rwx for a secret key)")


def registered_users(clients_dir: str | os.PathLike[str]) -> dict[bytes, str]:
    """``{public key (Z85): user name}`` of the ``<user>.key`` / ``<user>@<label>.key`` files in
    ``clients_dir`` (other key files are allowed to connect, but belong to nobody).

    Raises:
        InputError: one public key is in files of two different names (``root.key`` and
            ``alice.key``, or a named and an unnamed file): whose is it?
    """
    users: dict[bytes, str] = {}
    owners: dict[bytes, tuple[str | None, Path]] = {}
    for path in sorted(Path(clients_dir).glob("*.key")):
        match = _KEY_FILE_USER.match(path.name)
        user = match.group(1) if match is not None else None
        try:
            public, _secret = zmq.auth.load_certificate(path)
        except (OSError, ValueError) as error:
            log.warning("CURVE: ignoring client key %s: %s", path, error)
            continue
        first = owners.setdefault(public, (user, path))
        if first[0] != user:
            raise InputError(f"curve_clients_dir {clients_dir}: one public key is registered as {first[1].name} "
                             f"and as {path.name}; refusing to start (a key must name one user)")
        if user is not None:
            users[public] = user
    return users


def check_clients_dir(clients_dir: str | os.PathLike[str]) -> None:
    """The clients directory and every key file in it are the daemon's (:func:`curve_file_problem`).

    Raises:
        InputError: one line naming the file and what is wrong.
    """
    _refuse(clients_dir, "curve_clients_dir", curve_file_problem(clients_dir, CLIENTS_DIR_MODE, directory=True))
    for path in sorted(Path(clients_dir).glob("*.key")):
        _refuse(path, "CURVE client key", curve_file_problem(path, CLIENT_KEY_MODE))


def _user_authenticator(base: type[Any], users: Mapping[bytes, str]) -> Any:
    """pyzmq's authenticator whose ``User-Id`` for a registered key is its user's name."""

    class UserAuthenticator(base):  # type: ignore[misc, valid-type]
        def curve_user_id(self, client_public_key: bytes) -> str:
            return users.get(z85.encode(client_public_key), "")

    return UserAuthenticator


class CurveServer:
    """The daemon's CURVE setup: its key pair and the ZAP authenticator thread.

    It refuses (:class:`~hdeem_watch.errors.InputError`) a secret key or clients directory other
    users could read or replace (:func:`curve_file_problem`) and a key registered under two names.

    Args:
        context: the daemon's ZeroMQ context.
        secret_key_file: the daemon's ``.key_secret``.
        clients_dir: directory of allowed clients' public ``.key`` files (None = any client).
    """

    def __init__(self, context: zmq.Context[Any], secret_key_file: str, clients_dir: str | None) -> None:
        from zmq.auth.thread import ThreadAuthenticator

        _refuse(secret_key_file, "curve_secret_key_file", curve_file_problem(secret_key_file, SECRET_KEY_MODE))
        self.public, self.secret = load_secret_key(secret_key_file)
        if clients_dir is not None and not Path(clients_dir).is_dir():
            raise InputError(f"curve_clients_dir {clients_dir}: not a directory")
        if clients_dir is not None:
            check_clients_dir(clients_dir)
        self.users = registered_users(clients_dir) if clients_dir is not None else {}
        authenticator = _user_authenticator(ThreadAuthenticator, self.users)
        self.authenticator = authenticator(context, log=RefusalLog(log, {}))
        self.authenticator.start()
        self.authenticator.configure_curve(domain="*", location=clients_dir or zmq.auth.CURVE_ALLOW_ANY)

    def apply(self, sock: zmq.Socket[Any]) -> None:
        """Make ``sock`` a CURVE server with the daemon's keys."""
        secure_server(sock, self.public, self.secret)

    def close(self) -> None:
        """Stop the authenticator thread."""
        self.authenticator.stop()
