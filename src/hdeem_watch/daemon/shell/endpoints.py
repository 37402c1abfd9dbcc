"""Binding the daemon's sockets safely: private ipc directories, live-socket probes, own files only.

An ipc endpoint is a file, and files are shared with other users and other daemons:

* **The directory.** A directory the daemon creates is made 0750. The fallback runtime directory
  (``/tmp/hdeem-watch-<uid>``, in a world-writable ``/tmp``) must moreover be the daemon's own:
  created by ``mkdir`` (which fails if anything exists there), or, when it exists, a real directory
  (never a symlink) owned by the daemon's user with no more than mode 0750. Anything else is
  refused (:class:`~hdeem_watch.errors.InputError`): another user could have created it to
  replace the daemon's sockets by their own.
* **A live socket.** libzmq unlinks whatever is at the path before it binds, so a second daemon
  given the first one's endpoint would silently take it over. :func:`bind` first connects to an
  existing socket file: if someone answers, the endpoint is in use and nothing is touched; a
  stale file (connection refused) is replaced. A path that is not a socket is never replaced.
* **Permissions.** The socket is made 0660 through a descriptor that pins it (``O_PATH |
  O_NOFOLLOW``), never through a symlink planted in its place.
* **Clean-up.** :meth:`IpcFile.unlink_if_ours` removes the socket file only if it is still the
  one this process created (same device and inode), never a successor's.

TCP: :func:`~hdeem_watch.addresses.is_loopback` tells which endpoints stay on the node
(insecure TCP elsewhere needs ``allow_insecure_tcp``, see :mod:`hdeem_watch.config`).

Example:
    >>> import zmq, tempfile
    >>> sock = zmq.Context.instance().socket(zmq.PUB)
    >>> binding = bind(sock, f"ipc://{tempfile.mkdtemp()}/doc.sock")
    >>> oct(binding.ipc.path.stat().st_mode & 0o777)
    '0o660'
    >>> sock.close(0)
"""

from __future__ import annotations

import errno
import logging
import os
import socket
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zmq

from hdeem_watch.addresses import is_loopback, remote_endpoint
from hdeem_watch.errors import InputError
from hdeem_watch.wire.client import PRIVATE_DIR_MODE, directory_problem, fallback_runtime_dir, ipc_path

__all__ = ["Binding", "IpcFile", "advertised_endpoints", "bind", "bind_endpoint", "chmod_socket", "is_loopback",
           "private_directory"]

log = logging.getLogger("hdeem_watch.daemon")

#: Mode of a directory the daemon creates for its sockets, and the most an adopted fallback may have.
DIR_MODE = PRIVATE_DIR_MODE
#: Mode of an ipc socket file: the owner and the group may connect.
SOCKET_MODE = 0o660
#: Longest path of a Unix socket (sun_path holds 108 bytes with the terminating NUL).
MAX_IPC_PATH = 107


@dataclass(frozen=True)
class IpcFile:
    """An ipc socket file this process created (identified by device and inode)."""

    path: Path
    device: int
    inode: int

    def unlink_if_ours(self) -> bool:
        """Remove the file if it is still the one this process bound; True if it was removed."""
        try:
            st = os.lstat(self.path)
        except FileNotFoundError:
            return False
        if (st.st_dev, st.st_ino) != (self.device, self.inode):
            log.debug("%s belongs to another socket now; left alone", self.path)
            return False
        self.path.unlink(missing_ok=True)
        return True


@dataclass(frozen=True)
class Binding:
    """What :func:`bind` did: the endpoint actually bound and, for ipc, the file it created."""

    endpoint: str
    ipc: IpcFile | None = None


def bind(sock: zmq.Socket[Any], endpoint: str) -> Binding:
    """Bind ``sock`` to ``endpoint`` with the checks above.

    Returns:
        The endpoint actually bound (``tcp://*:0`` resolves to its port) and the ipc file.

    Raises:
        InputError: an unsafe runtime directory, a live socket of another process at the path, or
            a path that is not a socket.
        OSError: the directory cannot be created.
        zmq.ZMQError: the endpoint cannot be bound (in use, bad address).
    """
    path = ipc_path(endpoint)
    if path is None:
        sock.bind(endpoint)
        return Binding(_last_endpoint(sock))
    if len(str(path)) > MAX_IPC_PATH:
        raise OSError(errno.ENAMETOOLONG, f"ipc path longer than {MAX_IPC_PATH} bytes: {path}")
    private_directory(path.parent, strict=path.parent == fallback_runtime_dir())
    _refuse_live_socket(endpoint, path)
    sock.bind(endpoint)
    try:
        ipc = chmod_socket(path, SOCKET_MODE)
    except InputError:
        sock.unbind(endpoint)
        raise
    return Binding(_last_endpoint(sock), ipc)


def chmod_socket(path: Path, mode: int) -> IpcFile:
    """Set the mode of the socket file at ``path`` without ever following a symlink.

    The file is opened with ``O_PATH | O_NOFOLLOW`` (pinning the inode), checked to be a socket,
    and changed through ``/proc/self/fd``, so a symlink swapped in at the path cannot redirect the
    change to another file. Without ``/proc`` it falls back to ``lstat`` then ``chmod``.

    Raises:
        InputError: the path is not a socket (e.g. a symlink planted after the bind).
    """
    try:
        fd = os.open(path, os.O_PATH | os.O_NOFOLLOW)
    except OSError as error:
        raise InputError(f"{path}: the socket just bound is gone ({error.strerror})") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISSOCK(st.st_mode):
            raise InputError(f"{path}: not the socket just bound (replaced while binding); refusing to use it")
        pinned = f"/proc/self/fd/{fd}"
        if os.path.exists(pinned):
            os.chmod(pinned, mode)
        elif stat.S_ISSOCK(os.lstat(path).st_mode):
            os.chmod(path, mode)
    finally:
        os.close(fd)
    return IpcFile(path, st.st_dev, st.st_ino)


def bind_endpoint(sock: zmq.Socket[Any], endpoint: str) -> str:
    """:func:`bind`, returning only the endpoint bound."""
    return bind(sock, endpoint).endpoint


def private_directory(directory: Path, *, strict: bool) -> None:
    """Make sure ``directory`` exists; create it mode 0750, or check an existing one when ``strict``.

    Raises:
        InputError: ``strict`` and the directory is a symlink, not a directory, owned by another
            user or open to more than owner and group-read.
    """
    created = False
    if not os.path.lexists(directory):
        directory.parent.mkdir(parents=True, exist_ok=True)
        try:
            os.mkdir(directory, DIR_MODE)  # fails if anything appeared there meanwhile
            os.chmod(directory, DIR_MODE)
            created = True
        except FileExistsError:
            strict = True
    if not (strict or created):
        return
    problem = directory_problem(directory)
    if problem:
        raise InputError(f"runtime dir {directory}: {problem}; refusing to put the daemon's sockets there "
                         "(remove it, or set --runtime-dir / HDEEM_WATCH_RUNTIME_DIR)")


def _refuse_live_socket(endpoint: str, path: Path) -> None:
    """InputError when something listens at ``path`` or the path is not a socket at all."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    if not stat.S_ISSOCK(st.st_mode):
        raise InputError(f"{endpoint}: {path} exists and is not a socket; refusing to replace it")
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    probe.settimeout(1.0)
    try:
        probe.connect(str(path))
    except (ConnectionRefusedError, FileNotFoundError):
        return  # a stale file left by a daemon that died: bind replaces it
    except OSError as error:
        raise InputError(f"{endpoint}: cannot probe the existing socket ({error.strerror}); refusing to replace it") from None
    finally:
        probe.close()
    raise InputError(f"{endpoint}: endpoint in use by another daemon (a live socket at {path})")


def _last_endpoint(sock: zmq.Socket[Any]) -> str:
    bound = sock.getsockopt(zmq.LAST_ENDPOINT)
    return bound.decode() if isinstance(bound, bytes) else str(bound)


def advertised_endpoints(pub: str, controls: list[str], host: str | None = None) -> dict[str, str | None]:
    """What the status advertises to other nodes: ``{"pub": ..., "control": ...}``, each the TCP
    endpoint with this host's name (None where only a local endpoint is bound)."""
    name = host or socket.gethostname()
    remote_controls = [ep for ep in (remote_endpoint(c, name) for c in controls) if ep is not None]
    return {"pub": remote_endpoint(pub, name), "control": remote_controls[0] if remote_controls else None}
