"""Bounds of the control protocol (#22.1, #22.2): deep, huge, non-finite and non-Unicode bodies
are refused with an error code before or while parsing, and a reply that cannot be encoded
still gets answered."""

from __future__ import annotations

import json
from typing import Any

import pytest

from hdeem_watch.daemon.shell.control import Pending, dispatch
from hdeem_watch.wire import protocol
from hdeem_watch.wire.json_codec import MAX_REQUEST_DEPTH, nesting_depth
from hdeem_watch.wire.protocol import ProtocolError


def _code(data: bytes) -> str:
    with pytest.raises(ProtocolError) as info:
        protocol.decode_request(data)
    return info.value.code


@pytest.mark.parametrize("body", [b"[" * 5000, b"{" * 5000, b'{"op": "status", "args": {"m": ' + b"[" * 20_000 + b"]" * 20_000 + b"}}"],
                         ids=["arrays", "objects", "inside-args"])
def test_deep_nesting_is_bad_json_not_a_recursion_error(body: bytes) -> None:
    """A body nested thousands deep (once: RecursionError out of json.loads, a dead daemon) is bad-json."""
    assert _code(body) == "bad-json"
    reply = protocol.decode_reply(dispatch(body, {"status": lambda args: {}}))  # type: ignore[arg-type]
    assert not reply.ok and reply.code == "bad-json"
    assert protocol.request_id_of(body) is None


def test_the_depth_limit_is_exact_and_ignores_brackets_in_strings() -> None:
    """Depth MAX_REQUEST_DEPTH parses, one more does not; brackets inside strings are text."""
    inner = MAX_REQUEST_DEPTH - 2  # the request object and args are two levels
    ok = {"op": "x", "args": {"m": json.loads("[" * inner + "]" * inner), "s": "[[[[{{{{" * 100}}
    assert protocol.decode_request(json.dumps(ok).encode()).op == "x"
    too_deep = {"op": "x", "args": {"m": json.loads("[" * (inner + 1) + "]" * (inner + 1))}}
    assert _code(json.dumps(too_deep).encode()) == "bad-json"
    assert nesting_depth('"\\"[["') == 0


@pytest.mark.parametrize(
    ("body", "code"),
    [
        (b'{"op": "run.start", "args": {"elements": NaN}}', "bad-json"),
        (b'{"op": "run.start", "args": {"elements": Infinity}}', "bad-json"),
        (b'{"op": "run.start", "args": {"elements": -Infinity}}', "bad-json"),
        (b'{"op": "run.start", "args": {"elements": 1e400}}', "bad-args"),
        (b'{"op": "run.start", "args": {"elements": 99999999999999999999}}', "bad-args"),
        (b'{"op": "run.start", "args": {"elements": ' + b"9" * 5000 + b"}}", "bad-args"),
        (b'{"op": "run.start", "args": {"kernel": "\\ud800"}}', "bad-args"),
        (b'{"op": "run.start", "args": {"\\udfff": 1}}', "bad-args"),
        (b'{"op": "status", "id": "\\ud800x"}', "bad-args"),
    ],
)
def test_non_finite_huge_and_non_unicode_values_are_client_errors(body: bytes, code: str) -> None:
    """NaN/Infinity, numbers beyond a double or an int64, lone surrogates: a client error, not internal."""
    assert _code(body) == code
    reply = protocol.decode_reply(dispatch(body, {"run.start": lambda args: {}, "status": lambda args: {}}))  # type: ignore[arg-type]
    assert reply.code == code


def test_valid_extremes_still_parse() -> None:
    """The bounds refuse only what cannot be stored: int64 limits, 1e308 and paired surrogates pass."""
    args = protocol.decode_request(b'{"op": "x", "args": {"a": 9223372036854775807, "b": -9223372036854775807, '
                                   b'"c": 1e308, "d": "\\ud83d\\ude00"}}').args
    assert args == {"a": 2**63 - 1, "b": -(2**63 - 1), "c": 1e308, "d": "\N{GRINNING FACE}"}


def test_a_result_that_cannot_be_encoded_still_gets_a_reply() -> None:
    """An encode failure (once: no reply at all for run.stop, or the daemon's loop dying) is an internal reply."""
    deep: Any = []
    for _ in range(5000):
        deep = [deep]
    handlers: dict[str, Any] = {"deep": lambda args: {"x": deep}, "odd": lambda args: {"x": object()}}
    for op in handlers:
        reply = protocol.decode_reply(dispatch(json.dumps({"id": 7, "op": op}).encode(), handlers))  # type: ignore[arg-type]
        assert reply.id == 7 and not reply.ok and reply.code == "internal"
        assert op in reply.message


def test_a_pending_reply_that_cannot_be_encoded_is_an_error_reply() -> None:
    """ControlServer.complete turns an unencodable deferred result into an error reply, not an exception."""
    import zmq

    from hdeem_watch.daemon.shell.control import ControlServer

    context = zmq.Context.instance()
    server = ControlServer(context, "inproc://wire-bounds", {"stop": lambda args: Pending("stop")})
    client = context.socket(zmq.DEALER)
    client.connect("inproc://wire-bounds")
    try:
        client.send_multipart([b"", protocol.encode_request("stop", {}, 3)])
        pending: list[Pending] = []
        for _ in range(100):
            pending = server.handle()
            if pending:
                break
            client.poll(10)
        assert len(pending) == 1
        server.complete(pending[0], {"x": {1, 2}})
        assert client.poll(2000)
        reply = protocol.decode_reply(client.recv_multipart()[-1])
        assert reply.id == 3 and reply.code == "internal" and "stop" in reply.message
    finally:
        client.close(linger=0)
        server.close()


@pytest.mark.parametrize(("body", "request_id"), [
    (b'{"id": 41, "op": "job.start", "args": {"job_id": "1", "uid": 99999999999999999999}}', 41),
    (b'{"id": "p-41", "op": "job.start", "args": {"x": 1e400}}', "p-41"),
    (b'{"id": 41, "op": "job.start", "args": {"job_id": "' + b"7" * 100_000 + b'"}}', 41),
], ids=["int-out-of-range", "float-out-of-range", "too-large"])
def test_an_error_reply_echoes_the_id_whenever_it_can_be_read(body: bytes, request_id: Any) -> None:
    """A request refused for a value out of range or for its size still has a readable id: the
    reply carries it, so the caller's client takes it as the answer instead of waiting out its
    timeout (once: ``{"id": null}``)."""
    reply = protocol.decode_reply(dispatch(body, {"job.start": lambda args: {}}))  # type: ignore[arg-type]
    assert not reply.ok and reply.code in ("bad-args", "too-large")
    assert reply.id == request_id


def test_an_id_out_of_bounds_is_not_echoed() -> None:
    """Only an id the protocol allows comes back: not a 20-digit integer, a huge string or a float
    that overflows."""
    for body in (b'{"id": 99999999999999999999, "op": "ping"}', b'{"id": "' + b"i" * 300 + b'", "op": "x", "args": 5}',
                 b'{"id": 1e400, "op": "ping"}'):
        assert protocol.decode_reply(dispatch(body, {"ping": lambda args: {}})).id is None  # type: ignore[arg-type]
