"""Test-side MetricQ world: a real RabbitMQ broker, a MetricQ manager stand-in, a recording sink.

Loaded by ``conftest.py`` and ``benchmarks/bench_metricq.py`` with ``importlib`` (the tests run in
importlib mode).

* :class:`Broker` runs Debian's ``rabbitmq-server`` as a private node: its own node name, AMQP
  port, distribution port, ``epmd`` port, data and log directories under a temporary directory,
  so it needs no system-wide service and can be stopped and started again with its state.
* :class:`ManagerStandIn` answers the manager RPCs a source and a sink use, as the real
  metricq-manager does (github.com/metricq/metricq-manager, ``metricq_manager/manager.py`` and
  ``queue_manager.py`` at e42edb9): it declares the ``metricq.management`` (topic) and
  ``metricq.broadcast`` (fanout) exchanges and the durable ``management`` queue bound to ``#``
  (``Manager.connect``), the durable topic exchange ``metricq.data`` (``QueueManager.declare_exchanges``);
  ``source.register`` → ``{dataServerAddress (credentials stripped), dataExchange, config}``
  (``_source_register``); ``source.declare_metrics`` stores the metadata, ignoring the reserved
  ``source``/``historic`` fields, adding ``date`` and ``source = from_token`` (its CouchDB update is
  a dict here); ``sink.subscribe`` declares the data queue (the given ``dataQueue`` name or
  ``<token>-<uuid>-data``; non-durable, auto-delete, ``x-expires``), binds each metric as a routing
  key on ``metricq.data`` and answers ``{dataServerAddress, dataQueue, metrics: metadata}``
  (``handle_subscribe``, ``sink_declare_data_queue``); ``sink.unsubscribe`` unbinds. Not emulated:
  CouchDB configuration per token (every client gets ``config = {}``), history, databases,
  transformers, queue types and TTLs from configuration.
* :class:`RecordingSink` is a real :class:`metricq.Sink` that records every data point.
"""

from __future__ import annotations

import asyncio
import base64
import hashlib
import json
import os
import shutil
import signal
import socket
import subprocess
import time
import uuid
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import aio_pika
import numpy as np
from yarl import URL

import metricq
from metricq import Agent, Sink, rpc_handler

RABBITMQ_SERVER = Path("/usr/lib/rabbitmq/bin/rabbitmq-server")
EPMD = shutil.which("epmd") or "/usr/bin/epmd"
DEFAULT_SINK_QUEUE_EXPIRES_MS = 600_000


def free_port() -> int:
    """A free TCP port on the loopback interface."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def rabbitmq_available() -> bool:
    """Whether Debian's rabbitmq-server is installed here."""
    return RABBITMQ_SERVER.exists()


def definitions(vhosts: Sequence[str]) -> dict[str, Any]:
    """RabbitMQ definitions (``load_definitions``, read at boot) of ``vhosts`` with the guest user
    allowed everything in each. A node that loads definitions seeds no default user, so guest is
    defined here too, its password hashed as RabbitMQ's ``rabbit_password_hashing_sha256`` does:
    base64(salt + sha256(salt + password)) with a 4-byte salt."""
    salt = os.urandom(4)
    password_hash = base64.b64encode(salt + hashlib.sha256(salt + b"guest").digest()).decode()
    return {
        "users": [{"name": "guest", "password_hash": password_hash,
                   "hashing_algorithm": "rabbit_password_hashing_sha256", "tags": ["administrator"]}],
        "vhosts": [{"name": v} for v in vhosts],
        "permissions": [{"user": "guest", "vhost": v, "configure": ".*", "write": ".*", "read": ".*"}
                        for v in vhosts],
    }


class Broker:
    """A private RabbitMQ node in ``directory`` (state kept across :meth:`stop` / :meth:`start`)."""

    def __init__(self, directory: Path, vhosts: Sequence[str] = ()) -> None:
        self.directory = directory
        self.port = free_port()
        self.dist_port = free_port()
        self.epmd_port = free_port()
        self.name = f"hw{uuid.uuid4().hex[:8]}@localhost"
        self.proc: subprocess.Popen[bytes] | None = None
        for sub in ("home", "mnesia", "log"):
            (directory / sub).mkdir(parents=True, exist_ok=True)
        (directory / "enabled_plugins").write_text("[].\n")
        (directory / "env.conf").write_text("")
        if vhosts:  # created at boot from a definitions file: no rabbitmqctl (an Erlang VM each) per vhost
            (directory / "definitions.json").write_text(json.dumps(definitions(["/", *vhosts])))
            (directory / "rabbitmq.conf").write_text(f"load_definitions = {directory / 'definitions.json'}\n")

    @property
    def url(self) -> str:
        """The AMQP URL of the default vhost (the guest user, allowed from the loopback interface)."""
        return f"amqp://guest:guest@127.0.0.1:{self.port}/"

    def vhost_url(self, vhost: str) -> str:
        """The AMQP URL of ``vhost`` (one given to the constructor)."""
        return f"amqp://guest:guest@127.0.0.1:{self.port}/{vhost}"

    def env(self) -> dict[str, str]:
        d = self.directory
        return {
            **{k: v for k, v in os.environ.items() if not k.startswith(("RABBITMQ_", "ERL_"))},
            "HOME": str(d / "home"), "RABBITMQ_NODENAME": self.name, "RABBITMQ_NODE_IP_ADDRESS": "127.0.0.1",
            "RABBITMQ_NODE_PORT": str(self.port), "RABBITMQ_DIST_PORT": str(self.dist_port),
            "ERL_EPMD_PORT": str(self.epmd_port), "RABBITMQ_MNESIA_BASE": str(d / "mnesia"),
            "RABBITMQ_LOG_BASE": str(d / "log"), "RABBITMQ_CONFIG_FILE": str(d / "rabbitmq"),
            "RABBITMQ_ADVANCED_CONFIG_FILE": str(d / "advanced.config"),
            "RABBITMQ_ENABLED_PLUGINS_FILE": str(d / "enabled_plugins"),
            "RABBITMQ_CONF_ENV_FILE": str(d / "env.conf"), "RABBITMQ_PID_FILE": str(d / "pid"),
            "RABBITMQ_PLUGINS_EXPAND_DIR": str(d / "plugins-expand"),
        }

    def start(self, timeout_s: float = 90.0) -> Broker:
        """Start the node and wait until its AMQP port accepts connections."""
        with open(self.directory / "out.log", "ab") as out:
            self.proc = subprocess.Popen([str(RABBITMQ_SERVER)], env=self.env(), stdout=out, stderr=out,
                                         start_new_session=True)
        deadline = time.monotonic() + timeout_s
        while True:
            if self.proc.poll() is not None:
                raise RuntimeError(f"rabbitmq-server exited with {self.proc.returncode}: {self.log_tail()}")
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=0.2).close()
                return self
            except OSError:
                if time.monotonic() > deadline:
                    raise RuntimeError(f"rabbitmq-server not up after {timeout_s} s: {self.log_tail()}") from None
                time.sleep(0.2)

    def stop(self, timeout_s: float = 60.0) -> None:
        """Stop the node (SIGTERM to its process group: a clean shutdown keeping durable state)."""
        if self.proc is None or self.proc.poll() is not None:
            return
        os.killpg(self.proc.pid, signal.SIGTERM)
        try:
            self.proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(timeout=10)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:  # the Erlang VM may outlive the shell script briefly
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=0.2).close()
                time.sleep(0.2)
            except OSError:
                break

    def close(self) -> None:
        """Stop the node and its private ``epmd``."""
        self.stop()
        subprocess.run([EPMD, "-kill"], env=self.env(), capture_output=True, timeout=10, check=False)

    def log_tail(self) -> str:
        path = self.directory / "out.log"
        return path.read_text(errors="replace")[-2000:] if path.exists() else ""


class ManagerStandIn(Agent):
    """The manager RPCs of a source and a sink (see the module docstring for what is emulated)."""

    def __init__(self, url: str) -> None:
        super().__init__("manager", url)  # an Agent has no client version
        self.metadata: dict[str, dict[str, Any]] = {}
        self.registered: list[str] = []
        self.declarations: dict[str, int] = defaultdict(int)
        self.subscriptions: list[tuple[str, list[str]]] = []
        self._data_connection: Any = None
        self._management_queue: Any = None
        self.data_server_address = str(URL(url).with_user(None).with_password(None))

    async def connect(self) -> None:
        await super().connect()
        channel = self._management_channel
        assert channel is not None
        self._management_exchange = await channel.declare_exchange(
            "metricq.management", type=aio_pika.ExchangeType.TOPIC, durable=True)
        self._management_broadcast_exchange = await channel.declare_exchange(
            "metricq.broadcast", type=aio_pika.ExchangeType.FANOUT, durable=True)
        self._management_queue = await channel.declare_queue("management", durable=True, robust=True)
        await self._management_queue.bind(exchange=self._management_exchange, routing_key="#")
        self._data_connection = await self.make_connection(self._management_url, "manager data")
        data_channel = await self._data_connection.channel()
        await data_channel.declare_exchange("metricq.data", type=aio_pika.ExchangeType.TOPIC, durable=True)
        await data_channel.close()
        await self.rpc_consume([self._management_queue])

    async def teardown(self) -> None:
        if self._data_connection is not None:
            await self._data_connection.close()
        await super().teardown()

    @rpc_handler("source.register")
    async def _source_register(self, from_token: str, **body: Any) -> dict[str, Any]:
        self.registered.append(from_token)
        return {"dataServerAddress": self.data_server_address, "dataExchange": "metricq.data", "config": {}}

    @rpc_handler("source.declare_metrics")
    async def _declare_metrics(self, from_token: str, metrics: Any = None, **body: Any) -> None:
        if metrics is None:
            return
        if isinstance(metrics, list):
            metrics = {m: {} for m in metrics}
        date = time.strftime("%Y-%m-%dT%H:%M:%S+00:00", time.gmtime())
        for name, given in metrics.items():
            doc = dict(self.metadata.get(name, {}))
            given = {k: v for k, v in given.items() if k not in ("source", "historic") and not k.startswith("_")}
            doc.setdefault("date", date)
            doc.update(given)
            doc["source"] = from_token
            self.metadata[name] = doc
            self.declarations[name] += 1

    @rpc_handler("sink.subscribe")
    async def _subscribe(self, from_token: str, metadata: bool = True, **body: Any) -> dict[str, Any]:
        metrics = list(body.get("metrics", []))
        name = body.get("dataQueue") or f"{from_token}-{uuid.uuid4().hex}-data"
        expires = body.get("expires")
        expires_ms = int(1000 * expires) if isinstance(expires, (int, float)) and expires > 0 \
            else DEFAULT_SINK_QUEUE_EXPIRES_MS
        # After a broker restart a sink may ask before this side's own robust connection is back.
        await asyncio.wait_for(self._data_connection.connected.wait(), 60)
        channel = await self._data_connection.channel()
        try:
            queue = await channel.declare_queue(name, auto_delete=True, durable=False, robust=False,
                                                arguments={"x-expires": expires_ms})
            await asyncio.gather(*(queue.bind(exchange="metricq.data", routing_key=m) for m in metrics))
        finally:
            await channel.close()
        self.subscriptions.append((name, metrics))
        return {"dataServerAddress": self.data_server_address, "dataQueue": name,
                "metrics": {m: self.metadata.get(m, {}) for m in metrics} if metadata else metrics}

    @rpc_handler("sink.unsubscribe")
    async def _unsubscribe(self, from_token: str, dataQueue: str, metrics: list[str], **body: Any) -> dict[str, Any]:
        channel = await self._data_connection.channel()
        try:
            queue = await channel.declare_queue(dataQueue, passive=True, robust=False)
            await asyncio.gather(*(queue.unbind(exchange="metricq.data", routing_key=m) for m in metrics))
        finally:
            await channel.close()
        return {"dataServerAddress": self.data_server_address, "dataQueue": dataQueue,
                "metrics": {m: self.metadata.get(m, {}) for m in metrics}}


class RecordingSink(Sink):
    """A real MetricQ sink keeping every ``(time ns, value)`` per metric, and when each chunk came."""

    def __init__(self, url: str) -> None:
        super().__init__("sink-hdeem-watch-test", url, client_version="test")
        self.times: dict[str, list[np.ndarray]] = defaultdict(list)
        self.values: dict[str, list[np.ndarray]] = defaultdict(list)
        self.arrivals: dict[str, list[tuple[float, int]]] = defaultdict(list)
        self.count = 0

    async def _on_data_chunk(self, metric: str, data_chunk: Any) -> None:
        # Whole chunks as arrays (the per-point on_data of metricq.Sink is too slow for 64 nodes).
        t = np.cumsum(np.fromiter(data_chunk.time_delta, dtype=np.int64, count=len(data_chunk.time_delta)))
        v = np.fromiter(data_chunk.value, dtype=np.float64, count=len(data_chunk.value))
        self.times[metric].append(t)
        self.values[metric].append(v)
        self.arrivals[metric].append((time.time(), int(t[-1]) if t.size else 0))
        self.count += int(t.size)

    async def on_data(self, metric: str, timestamp: metricq.Timestamp, value: float) -> None:
        raise AssertionError("not used: _on_data_chunk records whole chunks")

    def series(self, metric: str) -> tuple[np.ndarray, np.ndarray]:
        """Every received ``(t_ns, values)`` of ``metric`` in arrival order."""
        if not self.times.get(metric):
            return np.zeros(0, np.int64), np.zeros(0)
        return np.concatenate(self.times[metric]), np.concatenate(self.values[metric])
