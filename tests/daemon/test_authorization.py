"""Authorization: state-changing ops only for root, the daemon's user and the owner of a running job.

On ipc the peer is the kernel's (SO_PEERCRED through libzmq's ``Peer-Address``): a client process
really runs as another user (a forked child that drops to ``nobody``). On TCP the peer is the
CURVE key's registered user (the ZAP handler's ``User-Id``).
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
import threading
import traceback
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import zmq

from hdeem_watch.config import DaemonSettings
from hdeem_watch.daemon.shell.authorization import STATE_CHANGING_OPS, Authorizer, Peer, ipc_peer, tcp_peer
from hdeem_watch.daemon.shell.control import ControlServer
from hdeem_watch.daemon.shell.security import CurveServer
from hdeem_watch.daemon.shell.service import Daemon
from hdeem_watch.sources.sim import SimSource
from hdeem_watch.wire import protocol
from hdeem_watch.wire.client import ControlClient, ControlError
from hdeem_watch.wire.keys import generate_keys, load_public_key, load_secret_key

NOBODY = 65534


def test_reading_is_open_and_changing_needs_root_the_daemon_user_or_a_job_owner() -> None:
    """The policy alone: every state-changing op is guarded, reads never are."""
    owners: set[int] = set()
    policy = Authorizer(job_owner_uids=lambda: frozenset(owners), daemon_uid=999)
    stranger, root, daemon_user = Peer("ipc", uid=1001, pid=7), Peer("ipc", uid=0), Peer("ipc", uid=999)
    for op in ("status", "ping", "runs.list", "calib.get", "baseline.get"):
        assert policy.refusal(op, stranger) is None and policy.refusal(op, Peer("tcp")) is None
    for op in sorted(STATE_CHANGING_OPS):
        refusal = policy.refusal(op, stranger)
        assert refusal is not None and refusal.startswith(op) and "uid 1001 (ipc, pid 7)" in refusal
        assert policy.refusal(op, root) is None and policy.refusal(op, daemon_user) is None
        assert policy.refusal(op, Peer("tcp")) is not None  # anonymous
    owners.add(1001)  # the job book says 1001 owns a running job: read at each request
    assert policy.refusal("run.start", stranger) is None
    owners.clear()
    assert policy.refusal("run.start", stranger) is not None


def test_peer_identities_come_from_libzmq_properties() -> None:
    """ipc: ``<addr>:uid:gid:pid``; tcp: a registered user name, never a key or a claim."""
    assert ipc_peer("localhost:1000:100:4242") == Peer("ipc", uid=1000, pid=4242, address="localhost:1000:100:4242")
    assert ipc_peer("").uid is None
    users = {"alice": 1000}.get
    assert tcp_peer("10.0.0.7", "alice", uid_of_user=users).uid == 1000
    assert tcp_peer("10.0.0.7", "bob", uid_of_user=users).uid is None
    z85_key = "rq:rM>}U?@Lns47E1%kR.o@n%FcmmsL/@{H8]yf7"  # pyzmq's default User-Id: the key itself
    assert tcp_peer("10.0.0.7", z85_key, uid_of_user=lambda name: 0).uid is None
    assert tcp_peer("10.0.0.7", None).describe() == "anonymous (tcp from 10.0.0.7, no registered CURVE client key)"


# ---------------------------------------------------------------------------------------------
# real sockets


def _call_as(uid: int, endpoint: str, op: str, args: dict[str, Any] | None = None) -> dict[str, Any]:
    """``op`` from a child process that runs as ``uid`` (fork, drop privileges, fresh context)."""
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
            reply = sock.recv_multipart()[-1] if sock.poll(10_000) else b'{"id":1,"ok":false,"error":{"code":"timeout","message":""}}'
            os.write(write_end, reply)
            sock.close()
            context.term()
            status = 0
        finally:
            os._exit(status)
    os.close(write_end)
    chunks = []
    with os.fdopen(read_end, "rb") as pipe:
        chunks.append(pipe.read())
    _, status = os.waitpid(pid, 0)
    assert status == 0
    reply = protocol.decode_reply(b"".join(chunks))
    return {"ok": reply.ok, "result": reply.result, "code": reply.code, "message": reply.message}


@pytest.fixture
def shared_dir() -> Iterator[Path]:
    """A socket directory another user can reach (pytest's tmp_path is root's alone)."""
    if os.geteuid() != 0:
        pytest.skip("needs root to run a client as another user")
    directory = Path(tempfile.mkdtemp(prefix="hw-authz-", dir="/tmp"))
    directory.chmod(0o755)
    try:
        yield directory
    finally:
        shutil.rmtree(directory, ignore_errors=True)


def _daemon_in(directory: Path, owners: set[int] | None) -> Iterator[Daemon]:
    settings = DaemonSettings(pub=f"ipc://{directory}/p.sock", control=f"ipc://{directory}/c.sock",
                              state_dir=str(directory / "s"), node="n", speed=20.0, heartbeat_s=0.2,
                              model_max_requests=100_000)
    uids = None if owners is None else (lambda: frozenset(owners))
    daemon = Daemon(settings, source=SimSource(seed=3, speed=20.0), job_owner_uids=uids)
    daemon.start()
    os.chmod(directory / "c.sock", 0o666)  # as if nobody were in the daemon's group
    loop = threading.Thread(target=daemon.run)
    loop.start()
    try:
        yield daemon
    finally:
        daemon.request_stop()
        loop.join()
        daemon.close()


@pytest.fixture
def in_process_daemon(shared_dir: Path) -> Iterator[tuple[Daemon, set[int]]]:
    """A daemon whose job owners the test sets."""
    owners: set[int] = set()
    for daemon in _daemon_in(shared_dir, owners):
        yield daemon, owners


@pytest.fixture
def job_daemon(shared_dir: Path) -> Iterator[Daemon]:
    """A daemon whose job owners are its own job book's (as in production)."""
    yield from _daemon_in(shared_dir, None)


@pytest.mark.slow
def test_the_owner_of_a_job_opened_by_the_prolog_may_announce_runs_until_it_ends(job_daemon: Daemon) -> None:
    """The job book decides: root's job.start for nobody's job lets nobody start a run on the node;
    after job.stop nobody is refused again."""
    endpoint = job_daemon.control_endpoint
    assert _call_as(NOBODY, endpoint, "run.start", {"kernel": "idle"})["code"] == "forbidden"
    assert _call_as(NOBODY, endpoint, "job.start", {"job_id": "77", "user": "nobody", "uid": NOBODY})["code"] == \
        "forbidden"  # a user cannot open a job window for themselves
    with ControlClient(endpoint, timeout_s=20) as root:
        root.call("job.start", {"job_id": "77", "user": "nobody", "uid": NOBODY, "nodes": ["n"], "cpus": 1})
        started = _call_as(NOBODY, endpoint, "run.start", {"kernel": "idle"})
        assert started["ok"], started
        assert _call_as(NOBODY, endpoint, "run.stop", {"run_id": started["result"]["run_id"], "abort": True})["ok"]
        root.call("job.stop", {"job_id": "77", "exit_code": 0})
    assert _call_as(NOBODY, endpoint, "run.start", {"kernel": "idle"})["code"] == "forbidden"


@pytest.mark.slow
def test_ipc_run_start_refused_for_another_user_allowed_for_root_and_the_job_owner(
        in_process_daemon: tuple[Daemon, set[int]], caplog: pytest.LogCaptureFixture) -> None:
    """The issue's rule on a real daemon: nobody gets ``forbidden`` for run.start (and may still
    read); root may; once nobody owns a running job, nobody may too."""
    daemon, owners = in_process_daemon
    endpoint = daemon.control_endpoint
    refused = _call_as(NOBODY, endpoint, "run.start", {"kernel": "idle"})
    assert not refused["ok"] and refused["code"] == "forbidden"
    assert f"uid {NOBODY} (ipc, pid" in refused["message"]
    assert _call_as(NOBODY, endpoint, "status")["ok"]
    assert any("refused run.start" in r.getMessage() for r in caplog.records)

    with ControlClient(endpoint, timeout_s=20) as root:
        run_id = root.call("run.start", {"kernel": "idle"})["run_id"]
        root.call("run.stop", {"run_id": run_id, "abort": True})

    owners.add(NOBODY)
    started = _call_as(NOBODY, endpoint, "run.start", {"kernel": "idle"})
    assert started["ok"], started
    stopped = _call_as(NOBODY, endpoint, "run.stop", {"run_id": started["result"]["run_id"], "abort": True})
    assert stopped["ok"], stopped


def _as_user(uid: int, action: Callable[[], int]) -> tuple[int, str]:
    """Run ``action`` in a forked child as ``uid``; its exit code and what it wrote to stderr."""
    read_end, write_end = os.pipe()
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child
        code = 70
        try:
            os.close(read_end)
            os.dup2(write_end, 2)
            sys.stderr = os.fdopen(2, "w")  # not pytest's capture
            os.setgroups([])
            os.setgid(uid)
            os.setuid(uid)
            code = action()
        except BaseException:
            traceback.print_exc()
        finally:
            sys.stderr.flush()
            os._exit(code)
    os.close(write_end)
    with os.fdopen(read_end, "rb") as pipe:
        err = pipe.read().decode()
    _, status = os.waitpid(pid, 0)
    return os.waitstatus_to_exitcode(status), err


@pytest.mark.slow
def test_whoami_and_bench_say_before_any_run_that_the_user_may_not(
        in_process_daemon: tuple[Daemon, set[int]]) -> None:
    """``whoami`` tells a client how the daemon sees it; ``bench --daemon`` stops with exit 1 and
    the reason before running a kernel, instead of a sweep without energies."""
    daemon, owners = in_process_daemon
    endpoint = daemon.control_endpoint
    me = _call_as(NOBODY, endpoint, "whoami")["result"]
    assert me["uid"] == NOBODY and me["transport"] == "ipc" and me["may_change_state"] is False
    assert me["reason"].startswith("changing state needs root")
    with ControlClient(endpoint) as root:
        assert root.call("whoami")["may_change_state"] is True

    from hdeem_watch.bench import announce  # noqa: F401  (the child cannot read root's Python library)
    from hdeem_watch.cli import bench, main  # noqa: F401

    code, err = _as_user(NOBODY, lambda: main(["bench", "--daemon", endpoint, "--kernels", "triad",
                                               "--elements", "1000", "--repeat", "1", "--json"]))
    assert code == 1, err
    assert "would not record runs from uid 65534 (ipc" in err and "run inside your SLURM job" in err
    owners.add(NOBODY)
    assert _call_as(NOBODY, endpoint, "whoami")["result"]["may_change_state"] is True


@pytest.fixture
def curve_server(tmp_path: Path, serve_control: Any) -> Iterator[Callable[..., Any]]:
    """A CURVE control server on loopback TCP whose clients dir registers ``root.key``."""
    context = zmq.Context()  # its own: the ZAP handler binds inproc://zeromq.zap.01 once per context
    server_public, server_secret = generate_keys(tmp_path / "server", "server")
    clients = tmp_path / "clients"
    _, root_secret = generate_keys(clients, "root")
    _, unnamed_secret = generate_keys(clients, "no-such-user-xyz")
    curve = CurveServer(context, str(server_secret), str(clients))
    server = ControlServer(context, "tcp://127.0.0.1:0", {"calib.reset": lambda args: {"reset": True},
                                                          "status": lambda args: {"up": True}},
                           secure=curve.apply, authorizer=Authorizer(daemon_uid=12345))

    def client(keys: tuple[bytes, bytes] | None) -> ControlClient:
        return ControlClient(server.endpoint, timeout_s=5, curve_server_key=load_public_key(server_public),
                             curve_client_keys=keys)

    client.root = load_secret_key(root_secret)  # type: ignore[attr-defined]
    client.unnamed = load_secret_key(unnamed_secret)  # type: ignore[attr-defined]
    try:
        with serve_control(server):
            yield client
    finally:
        server.close()
        curve.close()
        context.term()


def test_tcp_curve_a_registered_user_key_may_change_state_others_only_read(curve_server: Any) -> None:
    """root.key (registered for root) may reset the calibration; a key in the directory that
    names no user connects and reads, but is refused with ``forbidden``."""
    with curve_server(curve_server.root) as root:
        assert root.call("calib.reset") == {"reset": True}
    with curve_server(curve_server.unnamed) as other:
        assert other.call("status") == {"up": True}
        with pytest.raises(ControlError) as refused:
            other.call("calib.reset")
    assert refused.value.code == "forbidden"
    assert "no-such-user-xyz" in refused.value.message and "no such local user" in refused.value.message
