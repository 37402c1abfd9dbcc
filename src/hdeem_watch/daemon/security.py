"""CURVE encryption and authentication of the daemon's sockets (for remote TCP subscribers).

ZeroMQ's CURVE gives every connection encryption and server authentication; with a directory of
allowed client public keys it also authenticates the clients. Keys are ZeroMQ certificate files
(``zmq.auth`` format): :func:`generate_keys` writes ``<name>.key`` (public) and
``<name>.key_secret`` (public + secret).

Daemon: ``curve_secret_key_file`` (its ``.key_secret``) makes its TCP sockets CURVE servers;
``curve_clients_dir`` (a directory of clients' ``.key`` files) restricts who may connect (without it
any client that knows the server's public key may). A key file named ``<user>.key`` or
``<user>@<label>.key`` registers the key for that local user: the ZAP handler hands the user name
on as the connection's ``User-Id``, which authorizes state-changing requests
(:mod:`hdeem_watch.daemon.authorization`). Clients: :func:`secure_client` on any socket (SUB,
DEALER, REQ) with the server's public key; ``ControlClient(..., curve_server_key=...)`` does it for
control; :func:`client_curve` finds the keys a command-line client uses.

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
import re
import stat
from collections.abc import Mapping, MutableMapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zmq
import zmq.auth
from zmq.utils import z85

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


def generate_keys(directory: str | os.PathLike[str], name: str, *, force: bool = False) -> tuple[Path, Path]:
    """Write a new key pair ``<name>.key`` / ``<name>.key_secret`` (secret file mode 0600).

    Raises:
        InputError: a file of the pair exists already and ``force`` is not set (a new pair would
            lock out every client that holds the old public key).
    """
    target = Path(directory)
    if not force:
        for existing in (target / f"{name}.key", target / f"{name}.key_secret"):
            if os.path.lexists(existing):
                raise InputError(f"{existing}: exists already; refusing to replace the key pair (clients hold "
                                 "its public key): use --force to write a new one")
    target.mkdir(parents=True, exist_ok=True, mode=0o750)
    public, secret = zmq.auth.create_certificates(target, name)
    os.chmod(secret, 0o600)
    os.chmod(public, CLIENT_KEY_MODE)  # whatever the umask: the daemon refuses a key others may write
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


_KEY_FILE_USER = re.compile(r"^([a-z_][a-z0-9_.-]{0,31})(?:@[^/]*)?\.key$")

#: The most each CURVE file may allow: the daemon's secret key owner-read (group-read for a daemon
#: user in root's group), the clients directory and its public keys writable by their owner only.
SECRET_KEY_MODE, CLIENTS_DIR_MODE, CLIENT_KEY_MODE = 0o640, 0o755, 0o644


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


#: Environment variables of a client's keys: the daemon's public key (a ``.key`` file, or the key
#: itself in Z85) and the client's own ``.key_secret``.
SERVER_KEY_ENV = "HDEEM_WATCH_SERVER_KEY"
CLIENT_KEY_ENV = "HDEEM_WATCH_CLIENT_KEY"
#: The daemon's config file a client reads for ``curve_public_key_file`` (``$HDEEM_WATCH_CONFIG``
#: names another one).
CONFIG_ENV = "HDEEM_WATCH_CONFIG"
DEFAULT_CONFIG = "/etc/hdeem-watch/hdeem-watchd.toml"


@dataclass(frozen=True)
class ClientCurve:
    """The CURVE keys of a client: the daemon's public key, and this client's pair (None = an
    ephemeral pair, enough for a daemon that allows any client).

    Attributes:
        server_key: the daemon's public key (Z85, 40 bytes).
        client_keys: ``(public, secret)`` of this client, or None.
        source: where the server key came from (for messages).
    """

    server_key: bytes
    client_keys: tuple[bytes, bytes] | None = None
    source: str = ""


def _server_key_from(value: str, where: str) -> bytes:
    if len(value) == 40 and not os.path.exists(value):
        try:
            if len(z85.decode(value)) == 32:
                return value.encode()
        except (ValueError, KeyError):
            pass
    try:
        return load_public_key(value)
    except InputError as error:
        raise InputError(f"{where}: {error}") from None


def config_server_key_file(config_file: str | os.PathLike[str]) -> str | None:
    """The daemon's public key file named by its config file: ``curve_public_key_file``, else the
    ``.key`` beside ``curve_secret_key_file`` (None when the file names neither or is unreadable)."""
    from hdeem_watch.config import read_config_file

    try:
        data = read_config_file(config_file)
    except (InputError, OSError):
        return None
    table = data.get("daemon") if isinstance(data.get("daemon"), dict) else data
    assert isinstance(table, dict)
    public = table.get("curve_public_key_file")
    if isinstance(public, str) and public:
        return public
    secret = table.get("curve_secret_key_file")
    if isinstance(secret, str) and secret.endswith(".key_secret"):
        return secret[: -len("_secret")]
    return None


def client_curve(server_key_file: str | None = None, client_key_file: str | None = None, *,
                 env: Mapping[str, str] | None = None, home: str | os.PathLike[str] | None = None) -> ClientCurve | None:
    """The keys a command-line client uses for TCP endpoints, or None for no CURVE.

    The daemon's public key: ``server_key_file`` (``--server-key``), else ``$HDEEM_WATCH_SERVER_KEY``
    (a file or the Z85 key), else the node's daemon config (``$HDEEM_WATCH_CONFIG`` or
    /etc/hdeem-watch/hdeem-watchd.toml: ``curve_public_key_file``, or the ``.key`` beside
    ``curve_secret_key_file``) when that file exists. The client's own pair: ``client_key_file``
    (``--client-key``), else ``$HDEEM_WATCH_CLIENT_KEY``, else
    ``$XDG_CONFIG_HOME/hdeem-watch/client.key_secret`` when it exists, else an ephemeral pair.

    Raises:
        InputError: a key named by a flag or variable cannot be read (the message names it).
    """
    environ = os.environ if env is None else env
    server: bytes | None = None
    source = ""
    if server_key_file:
        server, source = _server_key_from(server_key_file, "--server-key"), server_key_file
    elif environ.get(SERVER_KEY_ENV):
        server, source = _server_key_from(environ[SERVER_KEY_ENV], f"${SERVER_KEY_ENV}"), f"${SERVER_KEY_ENV}"
    else:
        config = environ.get(CONFIG_ENV) or DEFAULT_CONFIG
        named = config_server_key_file(config) if os.path.exists(config) else None
        if named is not None and os.path.exists(named):
            server, source = _server_key_from(named, f"{config}: curve_public_key_file"), named
    if server is None:
        if client_key_file:
            raise InputError("--client-key needs the daemon's public key too (--server-key FILE or "
                             f"${SERVER_KEY_ENV})")
        return None
    return ClientCurve(server, _client_keys(client_key_file, environ, home), source)


def _client_keys(client_key_file: str | None, environ: Mapping[str, str],
                 home: str | os.PathLike[str] | None) -> tuple[bytes, bytes] | None:
    if client_key_file:
        where, path = "--client-key", client_key_file
    elif environ.get(CLIENT_KEY_ENV):
        where, path = f"${CLIENT_KEY_ENV}", environ[CLIENT_KEY_ENV]
    else:
        base = environ.get("XDG_CONFIG_HOME") or os.path.join(home or os.path.expanduser("~"), ".config")
        path = os.path.join(base, "hdeem-watch", "client.key_secret")
        if not os.path.exists(path):
            return None
        where = path
    try:
        return load_secret_key(path)
    except InputError as error:
        raise InputError(f"{where}: {error}") from None
