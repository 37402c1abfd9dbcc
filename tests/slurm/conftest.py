"""Real SLURM clusters on this machine for the SLURM tests: one node (``slurm``) and two (``two_node_cluster``).

The single-node cluster (munged + slurmctld + slurmd) follows the usual single-node recipe (munged, then slurmctld and slurmd from a scratch
directory on Debian's SLURM 22.05 packages), with ``TaskPlugin=task/affinity`` instead of
task/none so srun really binds tasks to CPUs (``--cpu-bind=none`` gives the unbound case). Needs root and the Debian packages slurmctld, slurmd,
slurm-client and munge (``.ci/run`` installs them). The cluster runs from a scratch directory with
its own free ports, with the hdeem-watch Prolog and Epilog of ``daemon/slurm/`` wired
in through small wrappers that set the hooks' settings (as ``/etc/hdeem-watch/slurm-hooks.env``
would). The node daemon's config file (``daemon.toml``: ipc endpoints and state in the scratch
directory, checkpoints every second) is the one the hooks read; no daemon runs unless a test starts
one (:meth:`Slurm.start_daemon`, as systemd would). Tests get a :class:`Slurm` with ``run(args)``
that sets ``SLURM_CONF``.

The module-scoped ``two_node_cluster`` fixture (below the single-node one) is a real two-node
SLURM on the same machine, for the allocation-wide tests:
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
"""

from __future__ import annotations

import contextlib
import json
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
BINARIES = ("munged", "slurmctld", "slurmd", "srun", "sbatch", "scontrol", "sinfo", "squeue")
#: The two-node cluster's nodes and the loopback address each node's daemon binds.
NODES = ("hwn1", "hwn2")
ADDRESSES = {"hwn1": "127.0.0.11", "hwn2": "127.0.0.12"}


@dataclass
class Slurm:
    """A running single-node cluster.

    ``hook_conf`` is the hooks' settings file (``HDEEM_WATCH_HOOK_CONF``): tests may write it and
    must remove it afterwards. ``daemon_config`` is the node daemon's config file; its control
    endpoint is ``control``.
    """

    root: Path
    conf: Path
    node: str
    cpus: int
    hook_dir: Path
    env: dict[str, str]
    daemon_config: Path
    control: str
    pub: str

    @property
    def hook_conf(self) -> Path:
        """The hooks' settings file."""
        return self.root / "hooks.env"

    def start_daemon(self, timeout_s: float = 30.0) -> subprocess.Popen[bytes]:
        """Start the node daemon with its config file (as systemd would) and wait until it answers."""
        from hdeem_watch.wire.client import ControlClient, DaemonUnreachable

        env = {k: v for k, v in self.env.items() if not k.startswith("HDEEM_WATCH_")}
        with open(self.root / "daemon.err", "ab") as err:
            proc = subprocess.Popen([sys.executable, "-m", "hdeem_watch", "daemon", "--config", str(self.daemon_config)],
                                    env=env, stdout=subprocess.DEVNULL, stderr=err)
        deadline = time.monotonic() + timeout_s
        with ControlClient(self.control, timeout_s=1.0) as client:
            while True:
                if proc.poll() is not None:
                    raise RuntimeError(f"daemon exited with {proc.returncode}: {(self.root / 'daemon.err').read_text()}")
                try:
                    client.call("ping")
                    return proc
                except DaemonUnreachable:
                    if time.monotonic() > deadline:
                        raise
                    time.sleep(0.05)

    def hook_records(self, job_id: str, event: str, timeout: float = 30) -> dict[str, object]:
        """Wait for the hooks' ``event`` line (``prolog``/``epilog``) of ``job_id`` in their
        jobs.jsonl (an Epilog finishes after srun returns)."""
        jobs = self.hook_dir / "jobs.jsonl"
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if jobs.exists():
                for line in jobs.read_text().splitlines():
                    record = json.loads(line)
                    if record.get("job_id") == job_id and record.get("event") == event:
                        return record  # type: ignore[no-any-return]
            time.sleep(0.1)
        log = (self.root / "slurmd.log").read_text()[-2000:]
        raise AssertionError(f"no {event} record of job {job_id}; slurmd log tail: {log}")

    def run(self, args: list[str], timeout: float = 60, **kwargs: object) -> subprocess.CompletedProcess[str]:
        """Run a SLURM client command against this cluster."""
        return subprocess.run(args, capture_output=True, text=True, env=self.env, timeout=timeout,
                              check=False, **kwargs)  # type: ignore[call-overload]


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
    raise RuntimeError("SLURM fixture: no TCP port free on every node address")


def _wait(predicate: Callable[[], bool], timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return
        time.sleep(0.1)
    raise RuntimeError(f"SLURM fixture: timed out waiting for {what}")


def _munge_ok() -> bool:
    try:
        cred = subprocess.run(["munge", "-n"], capture_output=True, timeout=5, check=False)
        if cred.returncode != 0:
            return False
        return subprocess.run(["unmunge"], input=cred.stdout, capture_output=True, timeout=5,
                              check=False).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


def _start_munge() -> int | None:
    """Start munged if no working one is running; return its pid if we started it."""
    if _munge_ok():
        return None
    key = Path("/etc/munge/munge.key")
    if not key.exists():
        subprocess.run(["runuser", "-u", "munge", "--", "mungekey", "--create"], check=True)
    run_dir = Path("/run/munge")
    run_dir.mkdir(parents=True, exist_ok=True)
    shutil.chown(run_dir, "munge", "munge")
    subprocess.run(["runuser", "-u", "munge", "--", "/usr/sbin/munged"], check=True)
    _wait(_munge_ok, 10, "munged")
    pid_file = run_dir / "munged.pid"
    return int(pid_file.read_text()) if pid_file.exists() else None


def _hook_wrapper(path: Path, hook: Path, env: dict[str, str], node_configs: Path | None = None) -> Path:
    """A Prolog/Epilog wrapper that exports the hooks' settings, then runs the real hook; with
    ``node_configs``, each node's hook reads that node's daemon config
    (``<node_configs>/$SLURMD_NODENAME/hdeem-watchd.toml``, as each real node has its own)."""
    exports = "".join(f"export {k}='{v}'\n" for k, v in env.items())
    if node_configs is not None:
        exports += f'export HDEEM_WATCH_CONFIG="{node_configs}/$SLURMD_NODENAME/hdeem-watchd.toml"\n'
    path.write_text(f"#!/bin/sh\n{exports}exec {hook}\n")
    path.chmod(0o755)
    return path


def _detected() -> tuple[int, int]:
    """CPUs and RealMemory (MB) as slurmd -C reports them."""
    out = subprocess.run(["slurmd", "-C"], capture_output=True, text=True, check=True).stdout
    fields = dict(item.split("=", 1) for item in out.split() if "=" in item)
    return int(fields["CPUs"]), int(fields["RealMemory"])


def _kill_pidfile(pid_file: Path) -> None:
    try:
        pid = int(pid_file.read_text())
    except (OSError, ValueError):
        return
    _stop_pid(pid)


def _stop_pid(pid: int) -> None:
    """SIGTERM, then SIGKILL after 10 s."""
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


@pytest.fixture(scope="session")
def slurm(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Slurm]:
    """Start munged (if needed), slurmctld and slurmd; stop what we started afterwards."""
    missing = [b for b in BINARIES if shutil.which(b) is None and not Path("/usr/sbin", b).exists()]
    if missing or os.geteuid() != 0:
        pytest.skip(f"real SLURM needs root and {', '.join(missing) or 'the SLURM packages'} "
                    "(apt-get install slurmctld slurmd slurm-client munge; .ci/run does)")
    root = tmp_path_factory.mktemp("slurm")
    os.chmod(root, 0o755)
    node = socket.gethostname().split(".")[0]
    cpus, memory = _detected()
    control, pub = f"ipc://{root}/run/control.sock", f"ipc://{root}/run/pub.sock"
    daemon_config = root / "daemon.toml"
    daemon_config.write_text(f'source = "sim"\nnode = "{node}"\ncontrol = "{control}"\npub = "{pub}"\n'
                             f'state_dir = "{root}/daemon-state"\njob_checkpoint_s = 1.0\n')
    hook_dir = root / "daemon-state" / "slurm-hooks"
    hook_env = {"HDEEM_WATCH_PYTHON": sys.executable, "HDEEM_WATCH_HOOK_CONF": str(root / "hooks.env"),
                "HDEEM_WATCH_CONFIG": str(daemon_config), "PYTHONPATH": str(REPO / "src")}
    prolog = _hook_wrapper(root / "prolog.sh", HOOKS / "prolog.sh", hook_env)
    epilog = _hook_wrapper(root / "epilog.sh", HOOKS / "epilog.sh", hook_env)
    conf = root / "slurm.conf"
    conf.write_text("\n".join([
        "ClusterName=hdeemwatch", "SlurmctldHost=localhost", "SlurmUser=root", "SlurmdUser=root",
        "AuthType=auth/munge", f"SlurmctldPort={_free_port()}", f"SlurmdPort={_free_port()}",
        f"StateSaveLocation={root}/state", f"SlurmdSpoolDir={root}/spool",
        f"SlurmctldPidFile={root}/slurmctld.pid", f"SlurmdPidFile={root}/slurmd.pid",
        f"SlurmctldLogFile={root}/slurmctld.log", f"SlurmdLogFile={root}/slurmd.log",
        "ProctrackType=proctrack/linuxproc", "TaskPlugin=task/affinity", "JobAcctGatherType=jobacct_gather/none",
        "AccountingStorageType=accounting_storage/none", "SelectType=select/cons_tres",
        "SelectTypeParameters=CR_Core", "SchedulerParameters=batch_sched_delay=0", "ReturnToService=2",
        "MpiDefault=none", f"Prolog={prolog}", f"Epilog={epilog}", "PrologFlags=Alloc",
        f"NodeName={node} NodeAddr=127.0.0.1 CPUs={cpus} RealMemory={max(1, memory - 512)} State=UNKNOWN",
        f"PartitionName=debug Nodes={node} Default=YES MaxTime=INFINITE State=UP", ""]))
    for sub in ("state", "spool"):
        (root / sub).mkdir()
    env = {k: v for k, v in os.environ.items() if not k.startswith("SLURM_")}
    env["SLURM_CONF"] = str(conf)
    env["PYTHONPATH"] = f"{REPO / 'src'}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"
    cluster = Slurm(root=root, conf=conf, node=node, cpus=cpus, hook_dir=hook_dir, env=env,
                    daemon_config=daemon_config, control=control, pub=pub)
    munge_pid = _start_munge()
    try:
        subprocess.run(["slurmctld", "-f", str(conf), "-c"], check=True, env=env)
        _wait(lambda: "UP" in cluster.run(["scontrol", "ping"]).stdout, 30, "slurmctld")
        subprocess.run(["slurmd", "-f", str(conf), "-N", node], check=True, env=env)

        def idle() -> bool:
            state = cluster.run(["sinfo", "-h", "-n", node, "-o", "%t"]).stdout.strip()
            if state.startswith(("drain", "down")):
                cluster.run(["scontrol", "update", f"NodeName={node}", "State=RESUME"])
            return state == "idle"

        _wait(idle, 60, "the node to become idle")
        yield cluster
    finally:
        jobs = cluster.run(["squeue", "-h", "-o", "%i"]).stdout.split()
        if jobs:
            cluster.run(["scancel", *jobs])
        _kill_pidfile(root / "slurmd.pid")
        _kill_pidfile(root / "slurmctld.pid")
        if munge_pid is not None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(munge_pid, signal.SIGTERM)


# --------------------------------------------------------------------------- the two-node cluster
def _two_node_conf(root: Path, prolog: str, epilog: str) -> str:
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
    from hdeem_watch.wire.client import ControlClient, DaemonUnreachable

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
    missing = [b for b in (*BINARIES, "unshare") if shutil.which(b) is None and not Path("/usr/sbin", b).exists()]
    if missing or os.geteuid() != 0:
        pytest.skip(f"a real two-node SLURM needs root and {', '.join(missing) or 'the SLURM packages'} "
                    "(apt-get install slurmctld slurmd slurm-client munge; .ci/run does)")
    from hdeem_watch.wire.keys import generate_keys

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
    prolog = _hook_wrapper(root / "prolog.sh", HOOKS / "prolog.sh", hook_env, node_configs=root)
    epilog = _hook_wrapper(root / "epilog.sh", HOOKS / "epilog.sh", hook_env, node_configs=root)
    conf.write_text(_two_node_conf(root, str(prolog), str(epilog)))
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
                # our child: wait() reaps it (_stop_pid's kill(pid, 0) would see the zombie 10 s)
                daemon.process.terminate()
                try:
                    daemon.process.wait(10)
                except subprocess.TimeoutExpired:
                    daemon.process.kill()
                    daemon.process.wait(10)
        if munge_pid is not None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(munge_pid, signal.SIGTERM)
