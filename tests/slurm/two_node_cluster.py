"""A real two-node SLURM on one machine, with one hdeem-watch daemon per node, for the allocation-wide tests.

Debian's SLURM 22.05 is built with multiple-slurmd support: two ``slurmd -N <name>`` processes
serve two nodes of one ``slurm.conf`` (distinct ``Port=`` per ``NodeName``, ``%n`` in the spool,
pid and log paths), and a job spans both (``srun -N2`` runs one task on each, ``SLURMD_NODENAME``
naming it). Checked before this fixture was written; it fails loudly (not skips) if that changes.

Each node's daemon (sim source) binds its TCP endpoints on a loopback address of its own
(``127.0.0.11``, ``127.0.0.12``), so both serve the one documented control port, as real nodes
do, and clients reach them by node name. The names resolve only where the "login node" resolves
them: clients run under ``unshare --mount`` with a private ``/etc/hosts`` bound over the real one
(:meth:`TwoNodeCluster.login_command`), so the machine's own resolver is never touched. Both
daemons use one CURVE key pair (a cluster's) and admit the clients in ``clients/``, where
``root.key`` is registered for root. The Prolog and Epilog are the project's hooks
(``daemon/slurm/``): each node's hook reads that node's daemon config (chosen by
``$SLURMD_NODENAME``, as each real node has its own ``/etc/hdeem-watch``) and talks to the daemon
over its local ipc socket, as root.

Needs root and the packages slurmctld, slurmd, slurm-client and munge (``.ci/run`` installs them).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
HOOKS = REPO / "daemon" / "slurm"
NODES = ("hwn1", "hwn2")
ADDRESSES = {"hwn1": "127.0.0.11", "hwn2": "127.0.0.12"}
BINARIES = ("munged", "slurmctld", "slurmd", "srun", "sbatch", "scontrol", "sinfo", "squeue", "unshare")


@dataclass
class NodeDaemon:
    """One node's hdeem-watch daemon."""

    node: str
    address: str
    directory: Path
    process: subprocess.Popen[bytes] | None = None

    @property
    def config(self) -> Path:
        """The daemon's config file (the one source of truth for the node's hooks too)."""
        return self.directory / "hdeem-watchd.toml"

    @property
    def local_control(self) -> str:
        """The node-local ipc control endpoint (for the node's own hooks)."""
        return f"ipc://{self.directory / 'run' / 'control.sock'}"

    def log(self) -> str:
        """The daemon's stderr so far."""
        path = self.directory / "daemon.log"
        return path.read_text(errors="replace") if path.exists() else ""


@dataclass
class TwoNodeCluster:
    """The running cluster and its daemons.

    Attributes:
        root: scratch directory of everything.
        conf: ``slurm.conf``.
        control_port: the daemons' control port (the same on both nodes).
        server_key: the daemons' public key; client_key: root's registered client pair.
        env: environment of SLURM clients (``SLURM_CONF``, ``PYTHONPATH``).
    """

    root: Path
    conf: Path
    control_port: int
    server_key: Path
    client_key: Path
    env: dict[str, str]
    daemons: dict[str, NodeDaemon] = field(default_factory=dict)

    def run(self, args: list[str], timeout: float = 60) -> subprocess.CompletedProcess[str]:
        """Run a SLURM client command against this cluster."""
        return subprocess.run(args, capture_output=True, text=True, env=self.env, timeout=timeout, check=False)

    def login_command(self, command: str) -> str:
        """``command`` (shell) as on a login node: node names resolve through a private hosts file."""
        return (f"unshare --mount sh -c 'mount --bind {self.root / 'hosts'} /etc/hosts && {command}'")

    def wait_for_job(self, job_id: str, timeout: float = 60) -> None:
        """Wait until the job has left the queue."""
        _wait(lambda: not self.run(["squeue", "-h", "-j", job_id]).stdout.strip(), timeout, f"job {job_id} to end")


def _wait(predicate: Callable[[], bool], timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return
        time.sleep(0.1)
    raise RuntimeError(f"two-node SLURM fixture: timed out waiting for {what}")


def _free_port(address: str = "127.0.0.1") -> int:
    with socket.socket() as s:
        s.bind((address, 0))
        return int(s.getsockname()[1])


def _port_free_everywhere(addresses: list[str]) -> int:
    """A TCP port that is free on every one of ``addresses`` (one control port for all nodes)."""
    for _ in range(50):
        port = _free_port(addresses[0])
        try:
            for address in addresses[1:]:
                with socket.socket() as s:
                    s.bind((address, port))
        except OSError:
            continue
        return port
    raise RuntimeError("two-node SLURM fixture: no TCP port free on every node address")


def _munge_ok() -> bool:
    try:
        cred = subprocess.run(["munge", "-n"], capture_output=True, timeout=5, check=False)
        return cred.returncode == 0 and subprocess.run(["unmunge"], input=cred.stdout, capture_output=True,
                                                       timeout=5, check=False).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


def _start_munge() -> int | None:
    """Start munged unless a working one runs; return its pid when this fixture started it."""
    if _munge_ok():
        return None
    if not Path("/etc/munge/munge.key").exists():
        subprocess.run(["runuser", "-u", "munge", "--", "mungekey", "--create"], check=True)
    run_dir = Path("/run/munge")
    run_dir.mkdir(parents=True, exist_ok=True)
    shutil.chown(run_dir, "munge", "munge")
    subprocess.run(["runuser", "-u", "munge", "--", "/usr/sbin/munged"], check=True)
    _wait(_munge_ok, 10, "munged")
    pid_file = run_dir / "munged.pid"
    return int(pid_file.read_text()) if pid_file.exists() else None


def _kill_pidfile(pid_file: Path) -> None:
    try:
        pid = int(pid_file.read_text())
    except (OSError, ValueError):
        return
    _stop_pid(pid)


def _stop_pid(pid: int) -> None:
    try:
        os.kill(pid, signal.SIGTERM)
    except ProcessLookupError:
        return
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return
        time.sleep(0.1)
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, signal.SIGKILL)


def _hook_wrapper(path: Path, hook: Path, env: dict[str, str], root: Path) -> Path:
    """A Prolog/Epilog wrapper: the hooks' settings, this node's daemon config, then the real hook."""
    exports = "".join(f"export {k}='{v}'\n" for k, v in env.items())
    config = f'export HDEEM_WATCH_CONFIG="{root}/$SLURMD_NODENAME/hdeem-watchd.toml"\n'
    path.write_text(f"#!/bin/sh\n{exports}{config}exec {hook}\n")
    path.chmod(0o755)
    return path


def _slurm_conf(root: Path, prolog: str, epilog: str) -> str:
    ports = {node: _free_port() for node in NODES}
    nodes = [f"NodeName={node} NodeHostname=localhost NodeAddr=127.0.0.1 Port={ports[node]} CPUs=1 "
             "RealMemory=100 State=UNKNOWN" for node in NODES]
    hooks = [f"Prolog={prolog}", f"Epilog={epilog}", "PrologFlags=Alloc"] if prolog else []
    return "\n".join([
        "ClusterName=hwtwonode", "SlurmctldHost=localhost", "SlurmUser=root", "SlurmdUser=root",
        "AuthType=auth/munge", f"SlurmctldPort={_free_port()}",
        f"StateSaveLocation={root}/state", f"SlurmdSpoolDir={root}/spool-%n",
        f"SlurmctldPidFile={root}/slurmctld.pid", f"SlurmdPidFile={root}/slurmd-%n.pid",
        f"SlurmctldLogFile={root}/slurmctld.log", f"SlurmdLogFile={root}/slurmd-%n.log",
        "ProctrackType=proctrack/linuxproc", "TaskPlugin=task/none", "JobAcctGatherType=jobacct_gather/none",
        "AccountingStorageType=accounting_storage/none", "SelectType=select/cons_tres",
        "SelectTypeParameters=CR_Core", "SchedulerParameters=batch_sched_delay=0", "ReturnToService=2",
        "MpiDefault=none", *hooks, *nodes,
        f"PartitionName=two Nodes={','.join(NODES)} Default=YES MaxTime=INFINITE State=UP", ""])


def _start_daemon(cluster: TwoNodeCluster, node: str, control_port: int, secret: Path, clients: Path) -> NodeDaemon:
    """Start a node's daemon from its own config file (``<node>/hdeem-watchd.toml``, as on a node)."""
    address = ADDRESSES[node]
    daemon = NodeDaemon(node, address, cluster.root / node)
    (daemon.directory / "run").mkdir(parents=True)
    daemon.directory.chmod(0o755)
    settings = {
        "source": "sim", "node": node, "speed": 10.0, "poll_interval_s": 0.05, "job_checkpoint_s": 1.0,
        "state_dir": str(daemon.directory / "state"), "runtime_dir": str(daemon.directory / "run"),
        "control": daemon.local_control, "pub": f"tcp://{address}:{_free_port(address)}",
        "remote_control": f"tcp://{address}:{control_port}",
        "curve_secret_key_file": str(secret), "curve_clients_dir": str(clients)}
    daemon.config.write_text("".join(f"{key} = {value!r}\n".replace("'", '"') for key, value in settings.items()))
    command = [sys.executable, "-m", "hdeem_watch", "daemon", "--config", str(daemon.config)]
    with open(daemon.directory / "daemon.log", "wb") as log:
        daemon.process = subprocess.Popen(command, env=cluster.env, stdout=subprocess.DEVNULL, stderr=log)
    return daemon


def _wait_for_daemon(daemon: NodeDaemon) -> None:
    from hdeem_watch.daemon.client import ControlClient, DaemonUnreachable

    def up() -> bool:
        assert daemon.process is not None
        if daemon.process.poll() is not None:
            raise RuntimeError(f"daemon of {daemon.node} exited: {daemon.log()[-2000:]}")
        try:
            with ControlClient(daemon.local_control, timeout_s=1.0) as client:
                client.call("ping")
        except DaemonUnreachable:
            return False
        return True

    _wait(up, 60, f"the daemon of {daemon.node}")


@pytest.fixture(scope="module")
def two_node_cluster(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TwoNodeCluster]:
    """munged (if needed), slurmctld, two slurmd (hwn1, hwn2) and a CURVE daemon per node."""
    missing = [b for b in BINARIES if shutil.which(b) is None and not Path("/usr/sbin", b).exists()]
    if missing or os.geteuid() != 0:
        pytest.skip(f"a real two-node SLURM needs root and {', '.join(missing) or 'the SLURM packages'} "
                    "(apt-get install slurmctld slurmd slurm-client munge; .ci/run does)")
    from hdeem_watch.daemon.security import generate_keys

    root = tmp_path_factory.mktemp("slurm2")
    os.chmod(root, 0o755)
    _public, secret = generate_keys(root / "keys", "server")
    clients = root / "clients"
    _, client_secret = generate_keys(root / "client", "root")
    clients.mkdir()
    shutil.copy(root / "client" / "root.key", clients / "root.key")
    (root / "hosts").write_text("127.0.0.1 localhost\n" + "".join(f"{a} {n}\n" for n, a in ADDRESSES.items()))
    conf = root / "slurm.conf"
    hook_env = {"HDEEM_WATCH_PYTHON": sys.executable, "HDEEM_WATCH_HOOK_CONF": str(root / "hooks.env"),
                "PYTHONPATH": str(REPO / "src")}
    prolog = _hook_wrapper(root / "prolog.sh", HOOKS / "prolog.sh", hook_env, root)
    epilog = _hook_wrapper(root / "epilog.sh", HOOKS / "epilog.sh", hook_env, root)
    conf.write_text(_slurm_conf(root, str(prolog), str(epilog)))
    (root / "state").mkdir()
    env = {k: v for k, v in os.environ.items() if not k.startswith("SLURM_")}
    env["SLURM_CONF"] = str(conf)
    env["PYTHONPATH"] = f"{REPO / 'src'}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"
    control_port = _port_free_everywhere(list(ADDRESSES.values()))
    cluster = TwoNodeCluster(root=root, conf=conf, control_port=control_port, server_key=root / "keys" / "server.key",
                             client_key=client_secret, env=env)
    munge_pid = _start_munge()
    try:
        for node in NODES:
            cluster.daemons[node] = _start_daemon(cluster, node, control_port, secret, clients)
        subprocess.run(["slurmctld", "-f", str(conf), "-c"], check=True, env=env)
        _wait(lambda: "UP" in cluster.run(["scontrol", "ping"]).stdout, 30, "slurmctld")
        for node in NODES:
            subprocess.run(["slurmd", "-f", str(conf), "-N", node], check=True, env=env)

        def idle() -> bool:
            states = cluster.run(["sinfo", "-h", "-N", "-o", "%N %t"]).stdout.split("\n")
            for line in filter(None, states):
                name, state = line.split()
                if state.startswith(("drain", "down")):
                    cluster.run(["scontrol", "update", f"NodeName={name}", "State=RESUME"])
            return sum(line.endswith(" idle") for line in states) == len(NODES)

        _wait(idle, 60, "both nodes to become idle")
        for daemon in cluster.daemons.values():
            _wait_for_daemon(daemon)
        yield cluster
    finally:
        jobs = cluster.run(["squeue", "-h", "-o", "%i"]).stdout.split()
        if jobs:
            cluster.run(["scancel", *jobs])
        for node in NODES:
            _kill_pidfile(root / f"slurmd-{node}.pid")
        _kill_pidfile(root / "slurmctld.pid")
        for daemon in cluster.daemons.values():
            if daemon.process is not None and daemon.process.poll() is None:
                _stop_pid(daemon.process.pid)
                daemon.process.wait(10)
        if munge_pid is not None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(munge_pid, signal.SIGTERM)
