"""Who may change the daemon's state: the pure policy and the peer identities it decides on.

Reading (``status``, ``runs.list``, ``calib.get``, the stream) is open to whoever can reach a socket.
The operations in :data:`STATE_CHANGING_OPS` are allowed per op (:data:`OP_CALLERS`):

* **operators** — root and the user the daemon runs as — may run every one of them: job windows
  are opened and closed by the SLURM Prolog and Epilog (root), baselines measured and the
  calibration reset by the node's administrators;
* **the owner of a job running on the node** (the job book's uids, injected as a callable) may
  announce runs (``run.start``, ``run.stop``) while that job runs, and nothing else: no job window
  of their own (which would outlive their job, also across a restart), none in another user's
  name, no stop of another user's job, no reset of the node's calibration;
* everybody else may only read.

A request's peer is known by the kernel or by its key, never by what it claims:

* on ``ipc://`` by the connecting process's credentials: libzmq reads ``SO_PEERCRED`` of every
  Unix-socket connection and appends ``:uid:gid:pid`` to the message property ``Peer-Address``
  (:func:`ipc_peer`);
* on ``tcp://`` by the CURVE client key: the daemon's ZAP handler maps a registered key to its
  user name (:mod:`hdeem_watch.daemon.shell.security`), which libzmq hands on as the property
  ``User-Id`` (:func:`tcp_peer`). A TCP peer without a registered key is anonymous: it may read,
  not change anything.

Example:
    >>> policy = Authorizer(job_owner_uids=lambda: frozenset({1000}), daemon_uid=999)
    >>> policy.refusal("status", Peer("tcp"))      # reading is open
    >>> policy.refusal("run.start", ipc_peer("localhost:1000:1000:42"))   # the job owner
    >>> print(policy.refusal("job.start", ipc_peer("localhost:1000:1000:42")))
    job.start needs root or the daemon's user; the peer is uid 1000 (ipc, pid 42)
    >>> print(policy.refusal("run.start", ipc_peer("localhost:1001:1001:43")))
    run.start needs root, the daemon's user or the owner of a job running on this node; the peer is uid 1001 (ipc, pid 43)
"""

from __future__ import annotations

import os
import pwd
import re
from collections.abc import Callable
from dataclasses import dataclass

#: Callers of an op: root and the daemon's user only.
OPERATORS = "operators"
#: Callers of an op: the operators and the owner of a job running on the node.
JOB_OWNERS = "job owners"

#: Who may call each control operation that changes the daemon's state (runs, jobs, baselines,
#: calibration); docs/protocol.md has the same table. Everything else (``ping``, ``status``,
#: ``runs.list``, ``jobs.list``, ``calib.get``, ``baseline.get``, ...) only reads and is open.
OP_CALLERS: dict[str, str] = {
    "run.start": JOB_OWNERS, "run.stop": JOB_OWNERS,
    "job.start": OPERATORS, "job.stop": OPERATORS,
    "baseline.measure": OPERATORS, "baseline.cancel": OPERATORS,
    "calib.reset": OPERATORS,
}
#: Every control operation that changes the daemon's state.
STATE_CHANGING_OPS: frozenset[str] = frozenset(OP_CALLERS)

#: The error code of a refused request.
FORBIDDEN = "forbidden"
#: Who may call an op of each kind, for messages.
RULES = {OPERATORS: "root or the daemon's user",
         JOB_OWNERS: "root, the daemon's user or the owner of a job running on this node"}
#: Who may change state at all (announce runs), for messages.
RULE = RULES[JOB_OWNERS]

_IPC_CREDENTIALS = re.compile(r":(\d+):(\d+):(\d+)$")


@dataclass(frozen=True)
class Peer:
    """Who sent a request, as far as the kernel or the key tells.

    Attributes:
        transport: ``"ipc"``, ``"tcp"`` or ``"inproc"``.
        uid: the peer's user id, None when unknown.
        pid: the peer process (ipc only).
        user: the user name of a registered CURVE key (tcp only).
        address: the peer address as libzmq gives it.
    """

    transport: str
    uid: int | None = None
    pid: int | None = None
    user: str | None = None
    address: str = ""

    def describe(self) -> str:
        """One phrase for a refusal and the log, e.g. ``uid 1001 (ipc, pid 43)``."""
        if self.uid is None:
            who = f"user {self.user!r} (no such local user)" if self.user else "anonymous"
        elif self.user:
            who = f"user {self.user} (uid {self.uid})"
        else:
            who = f"uid {self.uid}"
        where = self.transport
        if self.pid is not None:
            where += f", pid {self.pid}"
        elif self.address:
            where += f" from {self.address}"
        if self.transport == "tcp" and self.user is None:
            where += ", no registered CURVE client key"
        return f"{who} ({where})"


def ipc_peer(peer_address: str) -> Peer:
    """The peer of an ipc connection from libzmq's ``Peer-Address`` (``<addr>:uid:gid:pid``).

    libzmq appends the ``SO_PEERCRED`` credentials on Linux; without them the peer is anonymous.
    """
    match = _IPC_CREDENTIALS.search(peer_address)
    if match is None:
        return Peer("ipc", address=peer_address)
    return Peer("ipc", uid=int(match.group(1)), pid=int(match.group(3)), address=peer_address)


def local_uid(user: str) -> int | None:
    """The uid of a local user name (None when there is no such user)."""
    try:
        return pwd.getpwnam(user).pw_uid
    except (KeyError, UnicodeEncodeError):
        return None


def tcp_peer(peer_address: str, user_id: str | None, *,
             uid_of_user: Callable[[str], int | None] = local_uid) -> Peer:
    """The peer of a TCP connection: its CURVE key's registered user (``User-Id``), if any.

    A ``User-Id`` that is not a registered user name (pyzmq's default is the key itself, in Z85:
    40 characters) leaves the peer anonymous.
    """
    user = user_id or None
    if user is not None and not _is_user_name(user):
        user = None
    uid = uid_of_user(user) if user is not None else None
    return Peer("tcp", uid=uid, user=user, address=peer_address)


def _is_user_name(text: str) -> bool:
    return bool(re.fullmatch(r"[a-z_][a-z0-9_.-]{0,31}\$?", text))


class Authorizer:
    """The policy: who may run which operation (:data:`OP_CALLERS`).

    Args:
        job_owner_uids: the uids that own a job running on the node now (the job book's).
        daemon_uid: the user the daemon runs as (it may always control itself).
    """

    def __init__(self, *, job_owner_uids: Callable[[], frozenset[int]] = frozenset,
                 daemon_uid: int | None = None) -> None:
        self.job_owner_uids = job_owner_uids
        self.daemon_uid = os.geteuid() if daemon_uid is None else daemon_uid

    def is_operator(self, peer: Peer) -> bool:
        """Whether ``peer`` is root or the daemon's user."""
        return peer.uid is not None and peer.uid in (0, self.daemon_uid)

    def role(self, peer: Peer) -> str:
        """``root``, ``daemon user``, ``job owner`` (of a job running now) or ``other``."""
        if peer.uid == 0:
            return "root"
        if peer.uid is not None and peer.uid == self.daemon_uid:
            return "daemon user"
        if peer.uid is not None and peer.uid in self.job_owner_uids():
            return "job owner"
        return "other"

    def allowed_ops(self, peer: Peer) -> list[str]:
        """The state-changing ops ``peer`` may run now, sorted."""
        return sorted(op for op in STATE_CHANGING_OPS if self.refusal(op, peer) is None)

    def may_change_state(self, peer: Peer) -> bool:
        """Whether ``peer`` may announce runs now (``run.start``, ``run.stop``)."""
        return self.refusal("run.start", peer) is None

    def refusal(self, op: str, peer: Peer) -> str | None:
        """Why ``peer`` may not run ``op`` (one line), or None when it may."""
        callers = OP_CALLERS.get(op)
        if callers is None or self.is_operator(peer):
            return None
        if callers == JOB_OWNERS and peer.uid is not None and peer.uid in self.job_owner_uids():
            return None
        return f"{op} needs {RULES[callers]}; the peer is {peer.describe()}"
