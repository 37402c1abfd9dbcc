"""The wire protocol is unchanged on the wire (issue #26): real messages of the daemon as it was
before the wire package existed (tests/data/wire, recorded by its record.py; see its README) go
through today's decoder, subscriber core and request/reply codecs, and today's encoders make the
very same bytes of them."""

from __future__ import annotations

import base64
import json
import math
from pathlib import Path

import numpy as np
import pytest

from hdeem_watch.wire import protocol
from hdeem_watch.wire.subscriber import StreamFollower

DATA = Path(__file__).resolve().parents[1] / "data" / "wire"


def _stream() -> list[list[bytes]]:
    lines = (DATA / "stream.jsonl").read_text(encoding="utf-8").splitlines()
    return [[base64.b64decode(frame) for frame in json.loads(line)["frames"]] for line in lines]


def _control() -> list[tuple[bytes, bytes]]:
    lines = (DATA / "control.jsonl").read_text(encoding="utf-8").splitlines()
    return [(base64.b64decode(d["request"]), base64.b64decode(d["reply"])) for d in map(json.loads, lines)]


def test_the_recording_holds_every_kind_the_daemon_sent() -> None:
    kinds = {protocol.decode(frames).kind for frames in _stream()}
    assert kinds >= {"samples", "status", "run", "calib", "baseline", "counters", "job"}
    assert len(_control()) >= 10


@pytest.mark.parametrize("frames", _stream(), ids=lambda frames: frames[0].decode())
def test_a_recorded_stream_message_decodes_and_encodes_to_the_same_bytes(frames: list[bytes]) -> None:
    message = protocol.decode(frames)
    assert message.header["v"] == protocol.VERSION and message.node == "rec1"
    if message.kind == "samples":
        header = message.header
        t_ns, power_w = message.samples()
        assert t_ns.size == header["n"] > 0 and header["t0_ns"] == int(t_ns[0])
        assert np.all(np.diff(t_ns) > 0) and np.all(np.isfinite(power_w) | np.isnan(power_w))
        energy = math.nan if header["energy_j"] is None else header["energy_j"]
        encoder = protocol.SamplesEncoder(message.node, header["channel"], header["rate_hz"])
        again = encoder.frames(message.seq, message.t_ns, t_ns, power_w, energy, header["status"])
    else:
        assert message.payload == b""
        again = protocol.encode(message.topic, message.header, message.payload)
    assert again == frames


def test_the_subscriber_core_takes_the_recording_without_loss() -> None:
    follower = StreamFollower(None)
    taken = [follower.accept(frames, i) for i, frames in enumerate(_stream())]
    assert all(message is not None for message in taken)
    # the recorder kept each topic's first messages: consecutive sequence numbers, one daemon
    assert (follower.bad_messages, follower.gaps.missed, follower.gaps.restarts) == (0, 0, 0)
    status = next(m for m in taken if m is not None and m.kind == "status")
    plan = StreamFollower("ipc:///x/control.sock").plan({"node": status.node, "endpoints": {"pub": "ipc:///x/p"}}, 0,
                                                        subscribed=False)
    assert plan.subscription == b"hw1/rec1/"


@pytest.mark.parametrize("exchange", _control(), ids=lambda e: json.loads(e[1])["id"].__repr__())
def test_a_recorded_control_exchange_decodes_and_encodes_to_the_same_bytes(exchange: tuple[bytes, bytes]) -> None:
    request, reply_bytes = exchange
    reply = protocol.decode_reply(reply_bytes)
    if reply.ok:
        decoded = protocol.decode_request(request)
        assert decoded.id == reply.id and decoded.op
        again = protocol.encode_reply_ok(reply.id, reply.result)
    else:
        assert reply.code in protocol.ERROR_CODES and reply.message
        again = protocol.encode_reply_error(reply.id, reply.code, reply.message)
    assert again == reply_bytes
    assert protocol.request_id_of(request) == reply.id


def test_recorded_replies_carry_what_clients_read() -> None:
    replies = {protocol.decode_reply(reply).id: protocol.decode_reply(reply) for _request, reply in _control()}
    assert replies[1].result["pong"] is True
    assert replies[2].result["endpoints"]["pub"].startswith("ipc://")
    assert replies[4].result["run_id"] == replies[3].result["run_id"] and replies[4].result["dram_energy_j"] > 0
    assert replies[6].result["state"] == "done" and replies[6].result["job_id"] == "4242"
    assert replies[11].code == "unknown-op" and replies[12].code == "not-found"
    assert replies[None].code == "bad-json"
