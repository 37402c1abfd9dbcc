"""Control client of the node daemon, and where the daemon listens by default.

The daemon's control socket is a ROUTER; this client uses a DEALER (default) or a plain REQ
socket. Both send ``[b"", request]`` (the REQ envelope), so the daemon sees the same frames.
A request that gets no reply within ``timeout_s`` raises :class:`DaemonUnreachable`; the socket is
then recreated so a REQ client never stays stuck in its send/receive state machine, and a DEALER
client drops late replies to earlier requests by their ``id``. An error reply without an ``id``
(the daemon could not read one from the request: an ``id`` out of range) is the answer to the
request in flight: no earlier request can still be answered on this socket, as it is recreated
after every timeout.

On TCP a socket monitor (:class:`~hdeem_watch.wire.handshake.HandshakeWatch`) watches the
security handshake: a CURVE key the daemon refuses, a wrong server key or CURVE on one side only
raise :class:`HandshakeFailed` with the reason at once, instead of a silent wait for the timeout.
CURVE applies to TCP endpoints only (an ipc socket is protected by its file mode, and the daemon
knows its peers from the kernel).

Example:
    >>> client = ControlClient("ipc:///tmp/none/control.sock", timeout_s=0.1)
    >>> try:
    ...     client.call("status")
    ... except DaemonUnreachable as error:
    ...     print("unreachable")
    unreachable
    >>> client.close()
"""

from __future__ import annotations

import itertools
import os
import stat
import time
from pathlib import Path
from typing import Any, NoReturn

import zmq

from hdeem_watch.wire import protocol
from hdeem_watch.wire.handshake import HandshakeWatch

#: Environment variable that overrides the runtime directory of the default endpoints.
RUNTIME_DIR_ENV = "HDEEM_WATCH_RUNTIME_DIR"
PUB_SOCKET_NAME = "pub.sock"
CONTROL_SOCKET_NAME = "control.sock"


class ControlError(RuntimeError):
    """The daemon answered with an error reply.

    Attributes:
        code: the protocol error code (``unknown-op``, ``bad-args``, ``not-found``, ...).
        message: the daemon's one-line message.
    """

    def __init__(self, code: str, message: str) -> None:
        super().__init__(f"{code}: {message}")
        self.code = code
        self.message = message


class DaemonUnreachable(ConnectionError):
    """No reply from the daemon within the timeout (not running, wrong endpoint, or hung)."""


class HandshakeFailed(DaemonUnreachable):
    """The daemon refused this client's security handshake (wrong or unregistered key, CURVE on one
    side only); the message says which. Retrying does not help: the keys must change."""


def runtime_dir(explicit: str | os.PathLike[str] | None = None) -> Path:
    """The directory of the daemon's ipc sockets.

    ``explicit``, else ``$HDEEM_WATCH_RUNTIME_DIR``, else ``$XDG_RUNTIME_DIR/hdeem-watch``
    (``$RUNTIME_DIRECTORY`` under systemd), else ``/tmp/hdeem-watch-<uid>``.
    """
    if explicit is not None:
        return Path(explicit)
    env = os.environ.get(RUNTIME_DIR_ENV)
    if env:
        return Path(env)
    systemd = os.environ.get("RUNTIME_DIRECTORY")
    if systemd:
        return Path(systemd.split(":")[0])
    xdg = os.environ.get("XDG_RUNTIME_DIR")
    if xdg:
        return Path(xdg) / "hdeem-watch"
    return fallback_runtime_dir()


def fallback_runtime_dir() -> Path:
    """``/tmp/hdeem-watch-<uid>``: the runtime directory when nothing names one.

    It sits in a world-writable directory, so the daemon adopts it only when it is its own
    (:func:`hdeem_watch.daemon.shell.endpoints.private_directory`).
    """
    return Path(f"/tmp/hdeem-watch-{os.getuid()}")


#: The most a private socket directory may allow: owner all, group read and search.
PRIVATE_DIR_MODE = 0o750


def directory_problem(directory: str | os.PathLike[str]) -> str | None:
    """Why ``directory`` is not a private socket directory of this user, or None when it is.

    Private: a real directory (not a symlink) owned by the effective user, mode at most 0750.
    """
    try:
        st = os.lstat(directory)
    except FileNotFoundError:
        return "does not exist"
    if stat.S_ISLNK(st.st_mode):
        return "is a symlink"
    if not stat.S_ISDIR(st.st_mode):
        return "is not a directory"
    if st.st_uid != os.geteuid():
        return f"is owned by uid {st.st_uid}, not by this user (uid {os.geteuid()})"
    if st.st_mode & 0o7777 & ~PRIVATE_DIR_MODE:
        return f"has mode {st.st_mode & 0o7777:04o}; expected at most {PRIVATE_DIR_MODE:04o}"
    return None


def default_endpoints(runtime_dir_path: str | os.PathLike[str] | None = None) -> tuple[str, str]:
    """``(pub, control)`` ipc endpoints in the runtime directory (see :func:`runtime_dir`)."""
    base = runtime_dir(runtime_dir_path)
    return f"ipc://{base / PUB_SOCKET_NAME}", f"ipc://{base / CONTROL_SOCKET_NAME}"


def ipc_path(endpoint: str) -> Path | None:
    """The file of an ``ipc://`` endpoint, None for other transports."""
    return Path(endpoint[len("ipc://") :]) if endpoint.startswith("ipc://") else None


class ControlClient:
    """Synchronous request/reply client of the daemon's control socket (not thread-safe).

    Args:
        endpoint: the daemon's control endpoint, e.g. ``ipc:///run/hdeem-watch/control.sock``.
        timeout_s: how long :meth:`call` waits for a reply.
        socket_type: ``"dealer"`` (default) or ``"req"``.
        context: a ZeroMQ context (default: the process's shared instance).
        curve_server_key: the daemon's CURVE public key (Z85, 40 bytes) when it runs with CURVE;
            default for a TCP endpoint: the one the environment names (``$HDEEM_WATCH_SERVER_KEY``,
            else the node's daemon config; :func:`hdeem_watch.wire.keys.client_curve`).
        curve_client_keys: ``(public, secret)`` of this client (default: ``$HDEEM_WATCH_CLIENT_KEY``
            or ``~/.config/hdeem-watch/client.key_secret`` with an environment key, else an
            ephemeral pair).
        curve_from_environment: look for the keys in the environment when none are given (False:
            no CURVE unless ``curve_server_key``).

    Example:
        >>> with ControlClient("ipc:///tmp/x/control.sock", timeout_s=0.05) as c:  # doctest: +SKIP
        ...     c.call("status")["node"]
        'node7'
    """

    def __init__(
        self,
        endpoint: str,
        timeout_s: float = 5.0,
        *,
        socket_type: str = "dealer",
        context: zmq.Context[Any] | None = None,
        curve_server_key: bytes | None = None,
        curve_client_keys: tuple[bytes, bytes] | None = None,
        curve_from_environment: bool = True,
    ) -> None:
        if socket_type not in ("dealer", "req"):
            raise ValueError(f"socket_type {socket_type!r}: expected 'dealer' or 'req'")
        self.endpoint = endpoint
        self.timeout_s = float(timeout_s)
        self._type = zmq.DEALER if socket_type == "dealer" else zmq.REQ
        self._context = context or zmq.Context.instance()
        self._ids = itertools.count(1)
        self._socket: zmq.Socket[Any] | None = None
        self._watch: HandshakeWatch | None = None
        self._curve = (curve_server_key, curve_client_keys)
        self._curve_from_environment = curve_from_environment and curve_server_key is None

    def _connect(self) -> zmq.Socket[Any]:
        if self._socket is None:
            sock = self._context.socket(self._type)
            sock.setsockopt(zmq.LINGER, 0)
            tcp = self.endpoint.startswith("tcp://")
            server_key, client_keys = self._curve_keys() if tcp else self._curve
            if server_key is not None and tcp:
                from hdeem_watch.wire.keys import secure_client

                secure_client(sock, server_key, client_keys)
            if tcp:
                self._watch = HandshakeWatch(sock, curve=server_key is not None)
            sock.connect(self.endpoint)
            self._socket = sock
        return self._socket

    def _curve_keys(self) -> tuple[bytes | None, tuple[bytes, bytes] | None]:
        """The keys given, else (once) the environment's.

        Raises:
            InputError: a key the environment names cannot be read.
        """
        if self._curve_from_environment:
            from hdeem_watch.wire.keys import client_curve

            self._curve_from_environment = False
            found = client_curve()
            if found is not None:
                self._curve = (found.server_key, self._curve[1] or found.client_keys)
        return self._curve

    def _drop_socket(self) -> None:
        if self._watch is not None:
            self._watch.close()
            self._watch = None
        if self._socket is not None:
            self._socket.close(linger=0)
            self._socket = None

    def call(self, op: str, args: dict[str, Any] | None = None, *, timeout_s: float | None = None) -> Any:
        """Send one request and return its ``result``.

        Raises:
            ControlError: the daemon replied with an error.
            DaemonUnreachable: no reply within the timeout (or the ipc socket file is missing).
        """
        path = ipc_path(self.endpoint)
        if path is not None and not path.exists():
            raise DaemonUnreachable(f"{self.endpoint}: no daemon socket at {path}")
        if path is not None and path.parent == fallback_runtime_dir():
            # In world-writable /tmp another user may have put a socket of their own there.
            problem = directory_problem(path.parent)
            if problem is not None:
                raise DaemonUnreachable(f"{self.endpoint}: refusing to talk to it: {path.parent} {problem} "
                                        "(not this user's daemon)")
        request_id = next(self._ids)
        data = protocol.encode_request(op, args, request_id)
        reply = self._roundtrip(data, request_id, self.timeout_s if timeout_s is None else timeout_s)
        if not reply.ok:
            raise ControlError(reply.code, reply.message)
        return reply.result

    def _roundtrip(self, data: bytes, request_id: int, timeout_s: float) -> protocol.Reply:
        sock = self._connect()
        end = time.monotonic() + timeout_s
        self._send(sock, [b"", data] if self._type == zmq.DEALER else [data], end, timeout_s)
        poller = zmq.Poller()
        poller.register(sock, zmq.POLLIN)
        watch = self._watch
        if watch is not None:
            poller.register(watch.socket, zmq.POLLIN)
        remaining = max(1, int((end - time.monotonic()) * 1000))
        while remaining > 0:
            ready = dict(poller.poll(remaining))
            if not ready:
                break
            if watch is not None and watch.socket in ready and (failure := watch.read()) is not None:
                self._drop_socket()
                raise HandshakeFailed(f"{self.endpoint}: {failure}")
            if sock not in ready:
                remaining = int((end - time.monotonic()) * 1000)
                continue
            frames = sock.recv_multipart()
            try:
                reply = protocol.decode_reply(frames[-1])
            except protocol.ProtocolError as error:
                self._drop_socket()
                raise ControlError("bad-reply", str(error)) from None
            if reply.id == request_id or (reply.id is None and not reply.ok):
                return reply
            remaining = int((end - time.monotonic()) * 1000)  # a late reply to an earlier request
        self._give_up(timeout_s)

    def _send(self, sock: zmq.Socket[Any], frames: list[bytes], end: float, timeout_s: float) -> None:
        """Send ``frames`` by the monotonic time ``end``. A blocking send would wait for ever when the
        socket has no connection to queue on, as after a refused CURVE handshake tore it down: so
        the send waits, until ``end``, for the socket to take it or the handshake watch to fail."""
        poller: zmq.Poller | None = None  # only when the socket does not take the request at once
        watch = self._watch
        while True:
            try:
                sock.send_multipart(frames, zmq.NOBLOCK)
                return
            except zmq.Again:
                pass
            if poller is None:
                poller = zmq.Poller()
                poller.register(sock, zmq.POLLOUT)
                if watch is not None:
                    poller.register(watch.socket, zmq.POLLIN)
            remaining = int((end - time.monotonic()) * 1000)
            if remaining <= 0:
                self._give_up(timeout_s)
            ready = dict(poller.poll(remaining))
            if watch is not None and watch.socket in ready and (failure := watch.read()) is not None:
                self._drop_socket()
                raise HandshakeFailed(f"{self.endpoint}: {failure}")

    def _give_up(self, timeout_s: float) -> NoReturn:
        """Drop the socket and raise why no reply came: the handshake's failure, else the timeout."""
        failure = self._watch.failure if self._watch is not None else None
        self._drop_socket()
        if failure is not None:
            raise HandshakeFailed(f"{self.endpoint}: {failure}")
        raise DaemonUnreachable(f"{self.endpoint}: no reply within {timeout_s:g} s")

    def close(self) -> None:
        """Close the socket (the client can still be used again; it reconnects)."""
        self._drop_socket()

    def __enter__(self) -> ControlClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
