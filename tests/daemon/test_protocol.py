"""Wire protocol v1: topics, stream messages, sample batches, control requests and replies."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from hdeem_watch.wire import protocol
from hdeem_watch.wire.protocol import ProtocolError


def test_topics_round_trip_and_prefixes() -> None:
    """Topics are hw1/<node>/<kind>[/<channel>] and parse back; a node prefix does not match a longer node."""
    assert protocol.samples_topic("n1", "DDR_AB") == "hw1/n1/samples/DDR_AB"
    assert protocol.topic("n1", "status") == "hw1/n1/status"
    assert protocol.parse_topic("hw1/n1/samples/DDR_AB") == ("n1", "samples", "DDR_AB")
    assert protocol.parse_topic("hw1/n1/calib") == ("n1", "calib", None)
    prefix = protocol.subscription("n1")
    assert protocol.topic("n1", "run").encode().startswith(prefix)
    assert not protocol.topic("n10", "run").encode().startswith(prefix)
    assert protocol.samples_topic("n1", "CPU0").encode().startswith(protocol.subscription("n1", "samples"))
    assert not protocol.topic("n1", "status").encode().startswith(protocol.subscription("n1", "samples"))


@pytest.mark.parametrize("bad", ["hw2/n/status", "hw1/n", "hw1//status", "hw1/n/samples", "hw1/n/status/x", "x"])
def test_bad_topics_are_rejected(bad: str) -> None:
    """Anything that is not a v1 topic raises ProtocolError."""
    with pytest.raises(ProtocolError):
        protocol.parse_topic(bad)


def test_topic_builder_rejects_slashes_and_unknown_kinds() -> None:
    """Names with '/' and unknown kinds cannot make a topic (they would be ambiguous)."""
    with pytest.raises(ProtocolError):
        protocol.topic("a/b", "status")
    with pytest.raises(ProtocolError):
        protocol.topic("n", "nope")
    with pytest.raises(ProtocolError):
        protocol.topic("n", "samples")


def test_samples_message_layout_is_little_endian_times_then_watts() -> None:
    """A samples payload is n int64 LE ns then n float64 LE W, described by the header; NaN energy is null."""
    t = np.array([1_000, 11_000, 21_000], dtype=np.int64)
    p = np.array([1.25, np.nan, 3.0])
    frames = protocol.encode_samples(
        "node7", "BLADE", seq=5, rate_hz=100.0, t_wall_ns=t, power_w=p, energy_j=float("nan"), status="ok", t_ns=99
    )
    assert frames[0] == b"hw1/node7/samples/BLADE"
    header = json.loads(frames[1])
    assert header == {
        "v": 1, "seq": 5, "node": "node7", "t_ns": 99, "channel": "BLADE", "unit": "W", "rate_hz": 100.0,
        "n": 3, "dtype": "<f8", "t0_ns": 1_000, "dt_ns": 10_000_000, "energy_j": None, "status": "ok",
    }
    payload = frames[2]
    assert payload[:24] == t.astype("<i8").tobytes()
    assert payload[24:] == p.astype("<f8").tobytes()
    msg = protocol.decode(frames)
    times, watts = msg.samples()
    assert times.tolist() == t.tolist()
    assert watts[0] == 1.25 and math.isnan(watts[1]) and watts[2] == 3.0


@given(st.lists(st.tuples(st.integers(-(2**62), 2**62), st.floats(allow_nan=True, allow_infinity=True)), max_size=50))
def test_sample_batches_round_trip(pairs: list[tuple[int, float]]) -> None:
    """Any batch of (ns, W) pairs survives pack/unpack bit for bit."""
    t = np.array([a for a, _ in pairs], dtype=np.int64)
    p = np.array([b for _, b in pairs], dtype=np.float64)
    back_t, back_p = protocol.unpack_samples(protocol.pack_samples(t, p), len(pairs))
    assert back_t.tobytes() == t.tobytes()
    assert back_p.tobytes() == p.tobytes()


def test_decode_checks_frames_header_and_payload_size() -> None:
    """Wrong frame counts, versions, node mismatches and short payloads are ProtocolErrors."""
    good = protocol.encode("hw1/n/status", {"seq": 0, "node": "n", "t_ns": 1})
    assert protocol.decode(good).kind == "status"
    with pytest.raises(ProtocolError):
        protocol.decode(good[:2])
    with pytest.raises(ProtocolError):
        protocol.decode([good[0], b'{"v": 2, "seq": 0, "node": "n", "t_ns": 1}', b""])
    with pytest.raises(ProtocolError):
        protocol.decode([good[0], b'{"v": 1, "seq": 0, "node": "m", "t_ns": 1}', b""])
    with pytest.raises(ProtocolError):
        protocol.decode([good[0], b"not json", b""])
    frames = protocol.encode_samples(
        "n", "CPU0", seq=0, rate_hz=100.0, t_wall_ns=np.arange(4), power_w=np.ones(4), energy_j=1.0, status="ok"
    )
    with pytest.raises(ProtocolError):
        protocol.decode([frames[0], frames[1], frames[2][:-1]])


def test_encode_requires_seq_node_and_time() -> None:
    """A header without seq, node or t_ns cannot be encoded (every subscriber relies on them)."""
    with pytest.raises(ProtocolError):
        protocol.encode("hw1/n/status", {"node": "n", "t_ns": 1})
    with pytest.raises(ProtocolError):
        protocol.encode("hw1/n/status", {"seq": 0, "t_ns": 1})
    with pytest.raises(ProtocolError):
        protocol.encode("hw1/n/status", {"seq": 0, "node": "n", "t_ns": 1.5})


def test_json_is_strict_nan_becomes_null() -> None:
    """NaN and infinities go out as null and numpy values as plain JSON (never non-standard tokens)."""
    data = protocol.dumps({"a": float("nan"), "b": np.float64(2.5), "c": np.arange(2), "d": [float("inf")]})
    assert json.loads(data) == {"a": None, "b": 2.5, "c": [0, 1], "d": [None]}
    assert b"NaN" not in data


def test_sequence_counter_and_gap_tracker() -> None:
    """Sequence numbers are per topic from 0; the tracker counts the missing ones and spots restarts."""
    counter = protocol.SequenceCounter()
    assert [counter.next("a"), counter.next("a"), counter.next("b")] == [0, 1, 0]
    tracker = protocol.GapTracker()
    assert [tracker.observe("a", s) for s in (0, 1, 5, 6)] == [0, 0, 3, 0]
    assert tracker.observe("b", 7) == 0
    assert tracker.observe("a", 0) == 0
    assert tracker.missed == 3 and tracker.restarts == 1


def test_requests_and_replies() -> None:
    """Requests parse into (id, op, args); replies are ok/result or error code/message on one line."""
    req = protocol.decode_request(protocol.encode_request("run.start", {"kernel": "triad"}, "r1"))
    assert (req.id, req.op, req.args) == ("r1", "run.start", {"kernel": "triad"})
    assert protocol.decode_request(b'{"op": "status"}').args == {}
    ok = protocol.decode_reply(protocol.encode_reply_ok(3, {"x": float("nan")}))
    assert ok.ok and ok.id == 3 and ok.result == {"x": None}
    err = protocol.decode_reply(protocol.encode_reply_error(4, "bad-args", "line one\nline two"))
    assert not err.ok and err.code == "bad-args" and err.message == "line one line two"


_JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**53), 2**53) | st.floats() | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
    max_leaves=20)


@given(result=_JSON_VALUES, request_id=st.integers(0, 2**31) | st.text(max_size=6) | st.none())
def test_a_pre_encoded_result_gives_the_same_reply_bytes(result: object, request_id: object) -> None:
    """A result encoded once (a cached ``runs.list`` page) is spliced into each reply: the bytes are
    those of the reply of the value itself, NaN and infinities included (``null``), for any id."""
    encoded = protocol.EncodedResult.of(result)
    assert protocol.encode_reply_ok(request_id, encoded) == protocol.encode_reply_ok(request_id, result)
    assert protocol.decode_reply(protocol.encode_reply_ok(request_id, encoded)).result == encoded.decoded()


@pytest.mark.parametrize(
    ("data", "code"),
    [
        (b"\xff\xfe", "bad-json"),
        (b"[1, 2]", "bad-json"),
        (b"{", "bad-json"),
        (b'{"id": 1}', "bad-request"),
        (b'{"op": 5}', "bad-request"),
        (b'{"op": "status", "args": [1]}', "bad-request"),
        (b'{"op": "status", "id": {"x": 1}}', "bad-request"),
        (b'{"op": "status", "args": {"pad": "' + b"x" * protocol.MAX_REQUEST_BYTES + b'"}}', "too-large"),
    ],
)
def test_bad_requests_have_codes(data: bytes, code: str) -> None:
    """Each kind of malformed request maps to its error code."""
    with pytest.raises(ProtocolError) as info:
        protocol.decode_request(data)
    assert info.value.code == code


def test_request_id_recovered_for_error_replies() -> None:
    """The id of a request that fails validation is still echoed when it can be read."""
    assert protocol.request_id_of(b'{"id": "abc", "op": 5}') == "abc"
    assert protocol.request_id_of(b"garbage") is None
