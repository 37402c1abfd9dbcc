"""The CURVE keys of a client (and the key files of both sides).

Keys are ZeroMQ certificate files (``zmq.auth`` format): :func:`generate_keys` writes
``<name>.key`` (public) and ``<name>.key_secret`` (public + secret), for a daemon or for a client.
A client makes any socket (SUB, DEALER, REQ) a CURVE client of the daemon with
:func:`secure_client`; :func:`client_curve` finds the keys a command-line client uses (flags,
environment, the node's daemon config). The daemon's side (CURVE server, registered client keys)
is :mod:`hdeem_watch.daemon.shell.security`.

Example:
    >>> import tempfile, zmq
    >>> public, secret = generate_keys(tempfile.mkdtemp(), "server")
    >>> sock = zmq.Context.instance().socket(zmq.SUB)
    >>> secure_client(sock, load_public_key(public))
    >>> sock.close()
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zmq
import zmq.auth
from zmq.utils import z85

from hdeem_watch.errors import InputError

#: Mode of a written public key file, whatever the umask: the daemon refuses a client key others
#: may write.
PUBLIC_KEY_MODE = 0o644


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
    os.chmod(public, PUBLIC_KEY_MODE)  # whatever the umask: the daemon refuses a key others may write
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


def secure_client(sock: zmq.Socket[Any], server_public: bytes, client_keys: tuple[bytes, bytes] | None = None) -> None:
    """Make ``sock`` a CURVE client of the server with ``server_public`` (before it connects).

    ``client_keys`` = ``(public, secret)`` of the client; default an ephemeral pair (enough when the
    daemon allows any client).
    """
    public, secret = client_keys if client_keys is not None else zmq.curve_keypair()
    sock.setsockopt(zmq.CURVE_SERVERKEY, server_public)
    sock.setsockopt(zmq.CURVE_PUBLICKEY, public)
    sock.setsockopt(zmq.CURVE_SECRETKEY, secret)


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
