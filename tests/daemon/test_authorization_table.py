"""The authorization table of docs/protocol.md, op by op and caller by caller, on a real daemon.

The daemon is a process of its own running as its own user (``DAEMON_UID``: forked from the test
and switched to that user, keeping root's file access only, as the interpreter lives in root's home
where no other user can start it);
each caller is a process of its own running as root, as the daemon's user, as the owner of a job
the Prolog (root) opened, or as another user. The daemon knows each by the kernel's
``SO_PEERCRED``, never by what it claims. A job owner may announce runs while their job runs and
nothing else: no job of their own (which once kept their authority after their real job ended,
and across a ``kill -9`` and restart), none in another user's name, no stop of another user's job,
no baseline, no reset of the node's calibration.
"""

from __future__ import annotations

import ctypes
import os
import shutil
import signal
import tempfile
import time
import traceback
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import zmq

from hdeem_watch.config import DaemonSettings
from hdeem_watch.daemon.shell.authorization import OP_CALLERS, OPERATORS, STATE_CHANGING_OPS
from hdeem_watch.daemon.shell.service import Daemon
from hdeem_watch.sources.sim import SimSource
from hdeem_watch.wire import protocol

ROOT, DAEMON_UID, OWNER_UID, OTHER_UID = 0, 40001, 40002, 40003
#: The owner of the other job on the node (not a caller here).
SECOND_OWNER_UID = 40004
CALLERS = {"root": ROOT, "daemon user": DAEMON_UID, "job owner": OWNER_UID, "other user": OTHER_UID}
#: The job the Prolog opened for the job owner, and the second owner's.
OWNER_JOB, OTHERS_JOB = "8001", "8003"
#: Each state-changing op's arguments (valid ones: an allowed call must not fail for its arguments).
ARGS: dict[str, dict[str, Any]] = {
    "run.start": {"kernel": "idle"},
    "run.stop": {"run_id": "r-none", "abort": True},
    "job.start": {"job_id": "8002", "uid": OWNER_UID, "user": "owner"},
    "job.stop": {"job_id": OTHERS_JOB, "exit_code": 0},
    "baseline.measure": {"seconds": 0.2},
    "baseline.cancel": {},
    "calib.reset": {},
}


def _call_as(uid: int, endpoint: str, op: str, args: dict[str, Any] | None = None) -> protocol.Reply:
    """``op`` from a child process running as ``uid`` (fork, drop privileges, fresh context)."""
    read_end, write_end = os.pipe()
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child
        status = 1
        try:
            os.close(read_end)
            os.setgroups([])
            os.setgid(uid)
            os.setuid(uid)
            context = zmq.Context()
            sock = context.socket(zmq.DEALER)
            sock.setsockopt(zmq.LINGER, 0)
            sock.connect(endpoint)
            sock.send_multipart([b"", protocol.encode_request(op, args or {}, 1)])
            timeout = b'{"id":1,"ok":false,"error":{"code":"timeout","message":""}}'
            os.write(write_end, sock.recv_multipart()[-1] if sock.poll(20_000) else timeout)
            sock.close()
            context.term()
            status = 0
        finally:
            os._exit(status)
    os.close(write_end)
    with os.fdopen(read_end, "rb") as pipe:
        data = pipe.read()
    _, status = os.waitpid(pid, 0)
    assert status == 0
    return protocol.decode_reply(data)


def _become_daemon_user() -> None:
    """Run as :data:`DAEMON_UID` (real and effective user: what the daemon takes for its own user
    and what the kernel tells its peers), keeping root's file access (``setfsuid(0)``, allowed by
    the saved set-user-id 0) for the interpreter's library, which lies in root's private home."""
    os.setgroups([])
    os.setresgid(DAEMON_UID, DAEMON_UID, 0)
    os.setresuid(DAEMON_UID, DAEMON_UID, 0)
    libc = ctypes.CDLL(None, use_errno=True)
    libc.setfsuid(0)
    assert os.geteuid() == DAEMON_UID


class ForkedDaemon:
    """A sim daemon in a forked process running as :data:`DAEMON_UID`, in a directory others can reach."""

    def __init__(self, directory: Path) -> None:
        self.directory = directory
        self.control = f"ipc://{directory}/run/c.sock"
        self.pid = 0

    def start(self) -> ForkedDaemon:
        settings = DaemonSettings(pub=f"ipc://{self.directory}/run/p.sock", control=self.control,
                                  state_dir=str(self.directory / "state"), node="n", speed=20.0, heartbeat_s=0.2,
                                  model_max_requests=100_000)
        self.pid = os.fork()
        if self.pid == 0:  # pragma: no cover - the daemon
            code = 1
            try:
                _become_daemon_user()
                daemon = Daemon(settings, source=SimSource(seed=3, speed=20.0), context=zmq.Context())
                daemon.start()
                signal.signal(signal.SIGTERM, lambda *_: daemon.request_stop())
                daemon.run()
                daemon.close()
                code = 0
            except BaseException:
                traceback.print_exc()
            finally:
                os._exit(code)
        socket_path = self.directory / "run" / "c.sock"
        deadline = time.monotonic() + 30
        while not socket_path.exists() or _call_as(ROOT, self.control, "ping").code == "timeout":
            assert time.monotonic() < deadline, "the daemon did not start"
            assert os.waitpid(self.pid, os.WNOHANG) == (0, 0), "the daemon exited"
            time.sleep(0.1)
        os.chmod(socket_path, 0o666)  # as if every caller were in the daemon's group
        return self

    def stop(self, sig: int = signal.SIGTERM) -> None:
        if self.pid:
            os.kill(self.pid, sig)
            os.waitpid(self.pid, 0)
            self.pid = 0


@pytest.fixture
def daemon() -> Iterator[ForkedDaemon]:
    if os.geteuid() != 0:
        pytest.fail("needs root to run the daemon and its callers as other users")
    directory = Path(tempfile.mkdtemp(prefix="hw-authz-table-", dir="/tmp"))
    directory.chmod(0o755)
    for name in ("run", "state"):
        (directory / name).mkdir(mode=0o750)
        os.chown(directory / name, DAEMON_UID, DAEMON_UID)
    (directory / "run").chmod(0o755)
    forked = ForkedDaemon(directory).start()
    try:
        yield forked
    finally:
        forked.stop(signal.SIGKILL)
        shutil.rmtree(directory, ignore_errors=True)


def _prolog_opens_the_jobs(control: str) -> None:
    for job_id, uid in ((OWNER_JOB, OWNER_UID), (OTHERS_JOB, SECOND_OWNER_UID)):
        reply = _call_as(ROOT, control, "job.start", {"job_id": job_id, "uid": uid, "nodes": ["n"]})
        assert reply.ok, reply


@pytest.mark.slow
def test_each_op_as_root_the_daemon_user_a_job_owner_and_another_user(daemon: ForkedDaemon) -> None:
    """Every state-changing op, called by each kind of caller: refused ``forbidden`` exactly where
    the table says (the callers that may get the op's own answer: a result, ``not-found``,
    ``conflict``); reading is open to all; ``whoami`` names each caller's role and ops."""
    _prolog_opens_the_jobs(daemon.control)
    allowed = {"root": set(STATE_CHANGING_OPS), "daemon user": set(STATE_CHANGING_OPS),
               "job owner": {op for op, callers in OP_CALLERS.items() if callers != OPERATORS}, "other user": set()}
    assert allowed["job owner"] == {"run.start", "run.stop"}
    for caller in ("other user", "job owner", "daemon user", "root"):  # the operators last: they change the jobs
        uid = CALLERS[caller]
        me = _call_as(uid, daemon.control, "whoami").result
        assert me["uid"] == uid and set(me["allowed_ops"]) == allowed[caller], (caller, me)
        assert me["may_change_state"] is (caller != "other user")
        assert me["role"] == {"other user": "other"}.get(caller, caller)
        for op in ("status", "runs.list", "job.list", "calib.get", "baseline.get"):
            assert _call_as(uid, daemon.control, op).ok, (caller, op)
        for op in sorted(STATE_CHANGING_OPS):
            args = dict(ARGS[op], job_id=f"{ARGS[op]['job_id']}{uid}") if op == "job.start" else ARGS[op]
            reply = _call_as(uid, daemon.control, op, args)
            if op in allowed[caller]:
                assert reply.code != "forbidden", (caller, op, reply)
            else:
                assert reply.code == "forbidden" and f"uid {uid} (ipc" in reply.message, (caller, op, reply)
            if op == "run.start" and reply.ok:  # the run ends before the next caller's turn
                assert _call_as(uid, daemon.control, "run.stop", {"run_id": reply.result["run_id"],
                                                                    "abort": True}).ok
    with_root = _call_as(ROOT, daemon.control, "job.list").result["jobs"]
    assert {j["job_id"] for j in with_root} == {OWNER_JOB, OTHERS_JOB, f"8002{ROOT}", f"8002{DAEMON_UID}"}


@pytest.mark.slow
def test_a_job_owner_gets_no_lasting_authority(daemon: ForkedDaemon) -> None:
    """The probe's path: as a job owner, a job of one's own and one in another user's name are
    refused, another user's job cannot be closed, the calibration cannot be wiped; once root's
    Epilog closed the real job the owner may change nothing, also after a kill -9 and restart."""
    _prolog_opens_the_jobs(daemon.control)
    owner = OWNER_UID
    for op, args in (("job.start", {"job_id": "8002", "uid": owner}),
                     ("job.start", {"job_id": "8004", "uid": SECOND_OWNER_UID, "user": "probe2"}),
                     ("job.stop", {"job_id": OTHERS_JOB}), ("calib.reset", {})):
        assert _call_as(owner, daemon.control, op, args).code == "forbidden", (op, args)
    jobs = _call_as(ROOT, daemon.control, "status").result["jobs"]
    assert sorted(j["job_id"] for j in jobs) == [OWNER_JOB, OTHERS_JOB]
    assert _call_as(owner, daemon.control, "whoami").result["may_change_state"] is True
    assert _call_as(ROOT, daemon.control, "job.stop", {"job_id": OWNER_JOB, "exit_code": 0}).ok
    for restart in (False, True):
        if restart:
            daemon.stop(signal.SIGKILL)
            daemon.start()
        me = _call_as(owner, daemon.control, "whoami").result
        assert me["may_change_state"] is False and me["role"] == "other" and me["allowed_ops"] == [], me
        assert _call_as(owner, daemon.control, "run.start", {"kernel": "idle"}).code == "forbidden"
