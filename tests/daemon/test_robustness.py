"""The daemon under abuse: malformed requests, raw multipart junk, slow subscribers, REQ clients."""

from __future__ import annotations

import json
import random
import time
from typing import Any

import pytest
import zmq

from hdeem_watch.config import DaemonSettings
from hdeem_watch.wire import protocol


def _malformed(i: int, rng: random.Random) -> bytes:
    """The i-th malformed request: garbage, non-objects, bad fields, unknown ops, bad args, oversized."""
    kind = i % 10
    if kind == 0:
        return bytes(rng.getrandbits(8) for _ in range(rng.randint(0, 64)))
    if kind == 1:
        return json.dumps([1, 2, i]).encode()
    if kind == 2:
        return b'{"id": %d, "op": ' % i
    if kind == 3:
        return json.dumps({"id": i}).encode()
    if kind == 4:
        return json.dumps({"id": i, "op": f"no.such.op.{i}"}).encode()
    if kind == 5:
        return json.dumps({"id": i, "op": "run.stop", "args": {"run_id": [i]}}).encode()
    if kind == 6:
        return json.dumps({"id": i, "op": "baseline.measure", "args": {"seconds": -i}}).encode()
    if kind == 7:
        return json.dumps({"id": i, "op": "status", "args": "x" * 10}).encode()
    if kind == 8:
        return json.dumps({"id": i, "op": "runs.list", "args": {"limit": "ten"}}).encode()
    return json.dumps({"id": i, "op": "status", "args": {"pad": "x" * (protocol.MAX_REQUEST_BYTES + i)}}).encode()


@pytest.mark.slow
def test_1000_malformed_requests_get_errors_and_the_daemon_stays_healthy(shared_daemon: Any, receive: Any) -> None:
    """Every malformed, unknown or oversized request gets an error reply; samples keep flowing without gaps."""
    sub = shared_daemon.subscriber(protocol.subscription(shared_daemon.node, "samples") + b"DDR_AB")
    time.sleep(0.2)
    rng = random.Random(5)
    sock = zmq.Context.instance().socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(shared_daemon.control)
    codes: dict[str, int] = {}
    n = 1000
    for i in range(n):
        sock.send_multipart([b"", _malformed(i, rng)])
    poller = zmq.Poller()
    poller.register(sock, zmq.POLLIN)
    replies = 0
    while replies < n and poller.poll(10_000):
        frames = sock.recv_multipart()
        reply = protocol.decode_reply(frames[-1])
        assert not reply.ok
        codes[reply.code] = codes.get(reply.code, 0) + 1
        replies += 1
    sock.close()
    assert replies == n
    assert {"bad-json", "bad-request", "unknown-op", "bad-args", "too-large"} <= set(codes)
    with shared_daemon.client() as client:
        status = client.call("status")
    assert status["source"]["health"] == "ok"
    assert shared_daemon.proc.poll() is None
    batches = receive(sub, 0.5)
    sub.close()
    seqs = [m.seq for m in batches]
    assert len(seqs) > 5 and seqs == list(range(seqs[0], seqs[0] + len(seqs)))


@pytest.mark.slow
def test_raw_router_junk_is_survived(shared_daemon: Any) -> None:
    """Odd multipart shapes (many frames, empty frames, binary identities) neither crash nor wedge the daemon."""
    sock = zmq.Context.instance().socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(shared_daemon.control)
    sock.send_multipart([b""])
    sock.send_multipart([b"", b"", b"", b"{}"])
    sock.send_multipart([b"\x00\xff", b"junk"])
    sock.send(b'{"id": "plain", "op": "ping"}')  # a DEALER without the empty delimiter works too
    got = []
    poller = zmq.Poller()
    poller.register(sock, zmq.POLLIN)
    while poller.poll(500):
        got.append(protocol.decode_reply(sock.recv_multipart()[-1]))
    sock.close()
    assert any(r.ok and r.id == "plain" for r in got)
    with shared_daemon.client() as client:
        assert client.call("ping")["pong"] is True


@pytest.mark.slow
def test_plain_req_socket_and_req_client_work(shared_daemon: Any) -> None:
    """A plain REQ socket gets one-frame JSON replies; ControlClient in REQ mode works and raises on errors."""
    sock = zmq.Context.instance().socket(zmq.REQ)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.RCVTIMEO, 5000)
    sock.connect(shared_daemon.control)
    sock.send(protocol.encode_request("status", {}, "q1"))
    frames = sock.recv_multipart()
    sock.close()
    assert len(frames) == 1
    reply = json.loads(frames[0])
    assert reply["id"] == "q1" and reply["ok"] is True and reply["result"]["node"] == shared_daemon.node
    with shared_daemon.client(socket_type="req") as client:
        assert client.call("baseline.get").keys() == {"channels"}
        try:
            client.call("no.such.op")
        except Exception as error:
            assert getattr(error, "code", "") == "unknown-op"
        else:
            raise AssertionError("unknown op did not raise")
        assert client.call("ping")["pong"] is True


@pytest.mark.slow
def test_slow_subscriber_does_not_stall_the_others(daemon_factory: Any, receive: Any) -> None:
    """A subscriber that stops reading loses messages (visible as seq gaps); the others get every message."""
    # 200 messages per subscriber: ~0.7 s of stream, slack for a test process the loaded machine
    # deschedules; the slow one falls 2 s (~600 messages of up to 16 kB) behind.
    d = daemon_factory("--speed", "20", HDEEM_WATCH_SNDHWM="200").start()
    slow = d.subscriber(protocol.subscription(d.node), rcvhwm=5)
    fast = [d.subscriber(protocol.subscription(d.node)) for _ in range(2)]
    time.sleep(0.3)
    for sock in fast:
        receive(sock, 0.01)
    received = [receive(sock, 0.0) for sock in fast]
    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline:  # the fast ones keep reading; the slow one reads nothing
        for got, sock in zip(received, fast):
            got.extend(receive(sock, 0.05))
    late = receive(slow, 0.5)
    for sock in [slow, *fast]:
        sock.close()
    for got in received:
        tracker = protocol.GapTracker()
        for m in got:
            tracker.observe(m.topic, m.seq)
        assert tracker.missed == 0
        blade = [m for m in got if m.channel == "BLADE"]
        assert len(blade) > 0.5 * 2.0 / DaemonSettings().poll_interval_s  # kept up with the poll rate
        assert sum(1 for m in got if m.kind == "status") >= 2
    tracker = protocol.GapTracker()
    for m in late:
        tracker.observe(m.topic, m.seq)
    assert tracker.missed > 0  # the slow one lost messages instead of holding the daemon back
