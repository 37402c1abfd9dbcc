"""A bounded, seeded fuzz of the control socket against a real daemon process (#22, "done when").

Every op gets hostile arguments: nesting far beyond the limit, huge and non-finite numbers, lone
surrogates, wrong types and oversize frames. Each request must get a well-formed reply whose code
is a client error (never ``internal``), the daemon must stay up, and the sample stream must have no
gaps while it happens.
"""

from __future__ import annotations

import json
import random
import time
from typing import Any

import pytest
import zmq

from hdeem_watch.wire import protocol

#: The ops of protocol v1 and the argument names each one reads.
OPS: dict[str, tuple[str, ...]] = {
    "ping": (),
    "status": (),
    "run.start": ("kernel", "name", "threads", "elements", "repeat", "metadata"),
    "run.stop": ("run_id", "abort"),
    "runs.list": ("limit", "kernel"),
    "baseline.get": (),
    "baseline.measure": ("seconds",),
    "calib.get": (),
    "calib.reset": (),
}

#: Hostile JSON values as raw text (some are not strict JSON: that is the point).
_NUMBERS = ("1e308", "1e309", "-1e400", "1e300", "1e18", "-1", "0", "2.5", "9223372036854775808",
            "-9223372036854775809", "9" * 5000, "NaN", "Infinity", "-Infinity", "1e-320", "true", "null")
_STRINGS = ('"\\ud800"', '"\\udfff\\ud800"', '"ok\\udbff"', '"\\u0000"', '"' + "x" * 3000 + '"', '""',
            '"DDR/AB"', '"r1"', '"triad"', '"idle"')


def _nested(depth: int, rng: random.Random) -> str:
    open_, close = ("[", "]") if rng.random() < 0.5 else ('{"a":', "}")
    return open_ * depth + "1" + close * depth


def _hostile(rng: random.Random) -> str:
    kind = rng.random()
    if kind < 0.3:
        return _nested(rng.choice((31, 33, 100, 490, 1000, 5000)), rng)
    if kind < 0.6:
        return rng.choice(_NUMBERS)
    if kind < 0.85:
        return rng.choice(_STRINGS)
    return "[" + ",".join(rng.choice(_NUMBERS + _STRINGS) for _ in range(rng.randint(1, 5))) + "]"


def _request(i: int, rng: random.Random) -> tuple[bytes, bool]:
    """The i-th request text and whether its id can be recovered from it."""
    shape = rng.random()
    if shape < 0.05:
        return b"[" * rng.randint(1000, 60_000), False  # a bare deep body (#22.1)
    if shape < 0.08:
        pad = "x" * (protocol.MAX_REQUEST_BYTES + rng.randint(1, 50_000))
        return json.dumps({"id": i, "op": "status", "args": {"pad": pad}}).encode(), False  # too-large
    op = rng.choice(sorted(OPS))
    names = OPS[op] or ("x",)
    args = {name: _hostile(rng) for name in rng.sample(names, rng.randint(1, len(names)))}
    if op == "run.start" and rng.random() < 0.5:
        args["kernel"] = '"triad"'
    body = ",".join(f'"{name}":{value}' for name, value in args.items())
    if shape < 0.12:
        return f'{{"id":{_hostile(rng)},"op":"{op}","args":{{{body}}}}}'.encode(), False
    return f'{{"id":{i},"op":"{op}","args":{{{body}}}}}'.encode(), True


#: Client mistakes: none of them may be answered "internal".
CLIENT_ERRORS = {"bad-json", "bad-request", "too-large", "unknown-op", "bad-args", "not-found", "conflict",
                 "unavailable"}


@pytest.mark.slow
def test_fuzzed_requests_to_every_op_get_client_errors_and_the_stream_has_no_gaps(daemon_factory: Any,
                                                                                  receive: Any) -> None:
    """1200 seeded hostile requests: each gets a well-formed reply, none `internal`, the daemon lives, no gaps."""
    daemon = daemon_factory("--speed", "10", HDEEM_WATCH_SNDHWM="5000").start()
    sub = daemon.subscriber(protocol.subscription(daemon.node, "samples") + b"DDR_AB")
    time.sleep(0.3)
    receive(sub, 0.2)
    rng = random.Random(22)
    sock = zmq.Context.instance().socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(daemon.control)
    poller = zmq.Poller()
    poller.register(sock, zmq.POLLIN)
    codes: dict[str, int] = {}
    internal: list[str] = []
    seqs: list[int] = []
    n, batch = 1200, 100
    for start in range(0, n, batch):
        sent: dict[int, bytes] = {}
        for i in range(start, start + batch):
            body, has_id = _request(i, rng)
            sent[i if has_id else -i - 1] = body
            sock.send_multipart([b"", body])
        replies = 0
        while replies < batch and poller.poll(20_000):
            reply = protocol.decode_reply(sock.recv_multipart()[-1])  # well-formed, or this raises
            replies += 1
            assert reply.ok or reply.code in protocol.ERROR_CODES
            assert reply.id is None or isinstance(reply.id, str | int | float), reply
            code = "ok" if reply.ok else reply.code
            codes[code] = codes.get(code, 0) + 1
            if code == "internal":
                internal.append(f"{sent.get(reply.id, b'?')[:200]!r}: {reply.message}")
        assert replies == batch, f"{batch - replies} requests of batch {start} got no reply"
        seqs += [m.seq for m in receive(sub, 0.05)]
        # Close whatever run a valid run.start opened, so the next batch's starts are served too.
        with daemon.client(timeout_s=30) as client:
            for run in client.call("runs.list", {"limit": 5})["runs"]:
                if run["state"] == "running":
                    client.call("run.stop", {"run_id": run["run_id"], "abort": True})
    sock.close()
    assert daemon.proc.poll() is None, daemon.stderr()[-2000:]
    assert not internal, f"{len(internal)} client mistakes answered 'internal':\n" + "\n".join(internal[:10])
    assert {"bad-json", "bad-args", "too-large"} <= set(codes), codes
    seqs += [m.seq for m in receive(sub, 0.3)]
    sub.close()
    assert len(seqs) > 20 and seqs == list(range(seqs[0], seqs[0] + len(seqs))), "the sample stream had gaps"
    with daemon.client() as client:
        assert client.call("ping")["pong"] is True


@pytest.mark.slow
def test_a_frame_beyond_the_socket_limit_drops_only_that_peer(shared_daemon: Any) -> None:
    """A frame far beyond the request limit (ZMQ_MAXMSGSIZE) disconnects that peer; others are served."""
    sock = zmq.Context.instance().socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(shared_daemon.control)
    sock.send_multipart([b"", b"[" * (64 * protocol.MAX_REQUEST_BYTES + 1)])
    assert not sock.poll(500)  # no reply: the frame was never read
    sock.close()
    with shared_daemon.client() as client:
        assert client.call("ping")["pong"] is True
    assert shared_daemon.proc.poll() is None


@pytest.mark.slow
def test_absurd_run_sizes_are_refused(daemon_factory: Any) -> None:
    """run.start with an absurd size is bad-args (was accepted: the sim booked 4e290 J, the fit was poisoned).

    Its own daemon: an accepted absurd run poisons the energies of every later test on the daemon.
    """
    from hdeem_watch.wire.client import ControlError

    daemon = daemon_factory("--speed", "10", name="absurd").start()
    accepted = []
    with daemon.client(timeout_s=30) as client:
        for args in ({"elements": 1e300}, {"elements": 10**18}, {"threads": 10**9}, {"repeat": 10**15},
                     {"elements": 2.0}):
            try:
                started = client.call("run.start", {"kernel": "triad", **args})
            except ControlError as error:
                assert error.code == "bad-args", error
                continue
            accepted.append(args)
            client.call("run.stop", {"run_id": started["run_id"], "abort": True})
    assert not accepted, f"run.start accepted {accepted}"
