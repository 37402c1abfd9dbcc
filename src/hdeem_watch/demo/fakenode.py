"""A small stand-in daemon speaking wire protocol v1, for UI tests, benchmarks and development.

:class:`FakeNode` binds a PUB and a ROUTER socket on real endpoints and, in its own thread,
publishes HDEEM-shaped data (``BLADE`` at 1000 Sa/s and six regulator channels at 100 Sa/s, in
0.125 W steps), a status heartbeat every second, and answers the control operations the UI uses
(``status``, ``runs.list``, ``calib.get``, ``baseline.get``, ``baseline.measure``). It has no
model, no calibrator and no storage: it is not the daemon (``hdeem-watch daemon --source sim`` is),
only a cheap load generator with the daemon's wire format. ``skip_seq`` lets a test drop sequence
numbers on purpose, :meth:`FakeNode.inject` publish malformed frames.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from typing import Any

import numpy as np
import zmq

from hdeem_watch.wire import protocol

#: HDEEM's channels and native rates.
HDEEM_RATES_HZ = {
    "BLADE": 1000.0,
    "CPU0": 100.0,
    "CPU1": 100.0,
    "DDR_AB": 100.0,
    "DDR_CD": 100.0,
    "DDR_EF": 100.0,
    "DDR_GH": 100.0,
}
_BASE_W = {"BLADE": 180.0, "CPU0": 45.0, "CPU1": 42.0, "DDR_AB": 6.0, "DDR_CD": 5.5, "DDR_EF": 5.8, "DDR_GH": 6.2}


class FakeNode(threading.Thread):
    """A publisher thread with the daemon's wire format.

    Args:
        node: node name.
        pub: PUB endpoint to bind.
        control: ROUTER endpoint to bind.
        batch_s: publishing period of sample batches.
        seed: noise seed.
        context: ZeroMQ context.
    """

    def __init__(
        self,
        node: str,
        pub: str,
        control: str,
        *,
        batch_s: float = 0.1,
        seed: int = 0,
        context: zmq.Context[Any] | None = None,
    ) -> None:
        super().__init__(name=f"fake-node-{node}", daemon=True)
        self.node = node
        self.pub_endpoint = pub
        self.control_endpoint = control
        self.batch_s = batch_s
        self._context = context or zmq.Context.instance()
        self._rng = np.random.default_rng(seed)
        self._seq = protocol.SequenceCounter()
        self._halt = threading.Event()
        self._ready = threading.Event()
        self._energy_j = dict.fromkeys(HDEEM_RATES_HZ, 0.0)
        self._t0 = time.monotonic()
        self.skip_seq = 0
        self._inject: queue.Queue[list[bytes]] = queue.Queue()
        self.requests: list[tuple[str, dict[str, Any]]] = []
        self.baselines: dict[str, dict[str, Any]] = {}

    def start_and_wait(self, timeout_s: float = 5.0) -> FakeNode:
        """Start and wait until both sockets are bound."""
        self.start()
        if not self._ready.wait(timeout_s):
            raise RuntimeError(f"fake node {self.node} did not bind")
        return self

    def stop(self) -> None:
        """Stop publishing and unbind."""
        self._halt.set()
        self.join(5.0)

    def inject(self, frames: list[bytes]) -> None:
        """Publish raw frames (e.g. malformed ones) from the node's thread at its next wake-up."""
        self._inject.put(list(frames))

    def _send(self, pub: zmq.Socket[Any], frames: list[bytes]) -> None:
        pub.send_multipart(frames, copy=False)

    def _next_seq(self, topic: str) -> int:
        seq = self._seq.next(topic)
        if self.skip_seq > 0:
            self.skip_seq -= 1
            seq = self._seq.next(topic)
        return seq

    def run(self) -> None:
        pub = self._context.socket(zmq.PUB)
        pub.setsockopt(zmq.LINGER, 0)
        pub.setsockopt(zmq.SNDHWM, 100_000)
        pub.bind(self.pub_endpoint)
        ctl = self._context.socket(zmq.ROUTER)
        ctl.setsockopt(zmq.LINGER, 0)
        ctl.bind(self.control_endpoint)
        # a tcp://host:* endpoint binds an ephemeral port: publish the real endpoints
        self.pub_endpoint = pub.getsockopt(zmq.LAST_ENDPOINT).decode()
        self.control_endpoint = ctl.getsockopt(zmq.LAST_ENDPOINT).decode()
        self._ready.set()
        poller = zmq.Poller()
        poller.register(ctl, zmq.POLLIN)
        next_batch = time.monotonic()
        next_status = next_batch
        last_wall = time.time_ns()
        try:
            while not self._halt.is_set():
                timeout = max(0.0, min(next_batch, next_status) - time.monotonic())
                if poller.poll(int(timeout * 1000)):
                    self._serve(ctl, pub)
                while not self._inject.empty():
                    self._send(pub, self._inject.get_nowait())
                now = time.monotonic()
                if now >= next_batch:
                    wall = time.time_ns()
                    self._publish_batch(pub, last_wall, wall)
                    last_wall = wall
                    next_batch = max(next_batch + self.batch_s, now)
                if now >= next_status:
                    self._publish(pub, "status", self._status())
                    next_status = max(next_status + 1.0, now)
        finally:
            pub.close(linger=0)
            ctl.close(linger=0)

    def _publish(self, pub: zmq.Socket[Any], kind: str, body: dict[str, Any]) -> None:
        topic = protocol.topic(self.node, kind)
        header = {"seq": self._next_seq(topic), "node": self.node, "t_ns": time.time_ns(), **body}
        self._send(pub, protocol.encode(topic, header))

    def _publish_batch(self, pub: zmq.Socket[Any], t_from_ns: int, t_to_ns: int) -> None:
        phase = (time.monotonic() - self._t0) / 5.0
        for name, rate in HDEEM_RATES_HZ.items():
            dt_ns = int(1e9 / rate)
            first = (t_from_ns // dt_ns + 1) * dt_ns
            t = np.arange(first, t_to_ns + 1, dt_ns, dtype=np.int64)
            load = 1.0 + 0.5 * math.sin(phase + len(name))
            power = _BASE_W[name] * load + self._rng.normal(0.0, 0.3, len(t))
            power = np.round(power / 0.125) * 0.125
            self._energy_j[name] += float(power.sum()) / rate
            topic = protocol.samples_topic(self.node, name)
            self._send(
                pub,
                protocol.encode_samples(
                    self.node,
                    name,
                    seq=self._next_seq(topic),
                    rate_hz=rate,
                    t_wall_ns=t,
                    power_w=power,
                    energy_j=self._energy_j[name],
                    status="ok",
                ),
            )

    def _status(self) -> dict[str, Any]:
        return {
            "node": self.node,
            "endpoints": {"pub": self.pub_endpoint, "control": self.control_endpoint},
            "source": {"kind": "fake", "health": "ok"},
            "channels": {
                name: {"rate_hz": rate, "nominal_hz": rate, "gaps": 0, "status": "ok", "power_w": None,
                       "energy_j": self._energy_j[name]}
                for name, rate in HDEEM_RATES_HZ.items()
            },
            "process": {"cpu_percent": 0.5, "rss_bytes": 30_000_000},
            "run": None,
            "uptime_s": time.monotonic() - self._t0,
        }

    def _serve(self, ctl: zmq.Socket[Any], pub: zmq.Socket[Any]) -> None:
        frames = ctl.recv_multipart()
        envelope, data = frames[:-1], frames[-1]
        try:
            request = protocol.decode_request(data)
        except protocol.ProtocolError as error:
            ctl.send_multipart([*envelope, protocol.encode_reply_error(None, error.code, str(error))])
            return
        self.requests.append((request.op, request.args))
        result: Any
        if request.op == "status":
            result = self._status()
        elif request.op == "runs.list":
            result = {"runs": []}
        elif request.op == "calib.get":
            result = {"fit": None, "history": [], "truth": None}
        elif request.op == "baseline.get":
            result = {"channels": self.baselines}
        elif request.op == "baseline.measure":
            seconds = float(request.args.get("seconds", 10.0))
            self.baselines = {
                name: {"power_w": _BASE_W[name], "spread_w": 0.3, "n": 100, "t_ns": time.time_ns(), "origin": "quiet"}
                for name in HDEEM_RATES_HZ
            }
            self._publish(pub, "baseline", {"channels": self.baselines})
            result = {"seconds": seconds}
        else:
            ctl.send_multipart([*envelope, protocol.encode_reply_error(request.id, "unknown-op", request.op)])
            return
        ctl.send_multipart([*envelope, protocol.encode_reply_ok(request.id, result)])
