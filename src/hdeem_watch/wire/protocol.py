"""Wire protocol v1 between the node daemon and its clients (TUI, bench, exporters).

Stream (ZeroMQ PUB/SUB): every message has three frames ``[topic, header, payload]``:

* ``topic``: UTF-8, ``hw1/<node>/<kind>`` or ``hw1/<node>/samples/<channel>``; kinds are
  ``samples``, ``status``, ``run``, ``calib``, ``baseline`` and ``alarm`` (:data:`KINDS`). Subscribing to a
  prefix (``hw1/node7/``, ``hw1/node7/samples/``) selects nodes and kinds.
* ``header``: a UTF-8 JSON object with at least ``"v": 1``, ``"seq"`` (per topic, +1 each message,
  so a subscriber sees gaps), ``"node"`` and ``"t_ns"`` (wall clock, integer ns). NaN is sent as
  ``null``.
* ``payload``: bytes. For samples: ``n`` int64 little-endian wall-clock ns, then ``n`` float64
  little-endian watts (NaN = unknown). Empty for every other kind. Never pickle.

Control (ROUTER; a REQ or DEALER client works): one JSON frame per request
``{"id": ..., "op": "...", "args": {...}}``, replied with ``{"id": ..., "ok": true, "result": ...}``
or ``{"id": ..., "ok": false, "error": {"code": "...", "message": "..."}}``.

The full description is in ``docs/protocol.md``. This module is pure: no sockets.

Example:
    >>> import numpy as np
    >>> frames = encode_samples("n1", "DDR_AB", seq=0, rate_hz=100.0,
    ...                         t_wall_ns=np.array([10, 20]), power_w=np.array([1.5, np.nan]),
    ...                         energy_j=3.0, status="ok")
    >>> msg = decode(frames)
    >>> msg.kind, msg.channel, msg.seq
    ('samples', 'DDR_AB', 0)
    >>> msg.samples()[1].tolist()
    [1.5, nan]
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hdeem_watch.wire.json_codec import (
    ERROR_CODES,
    MAX_REQUEST_BYTES,
    MAX_REQUEST_DEPTH,
    ProtocolError,
    dumps,
    jsonable,
    loads_object,
    quoted,
)
from hdeem_watch.wire.requests import (
    EncodedResult,
    Reply,
    Request,
    decode_reply,
    decode_request,
    encode_reply_error,
    encode_reply_ok,
    encode_request,
    request_id_of,
)

__all__ = [
    "ERROR_CODES", "KINDS", "MAX_REQUEST_BYTES", "MAX_REQUEST_DEPTH", "SAMPLE_DTYPE", "TIME_DTYPE", "TOPIC_PREFIX",
    "VERSION", "EncodedResult", "GapTracker", "Message", "ProtocolError", "Reply", "Request", "SamplesEncoder",
    "SequenceCounter", "decode", "decode_reply", "decode_request", "dumps", "encode", "encode_reply_error",
    "encode_reply_ok", "encode_request", "encode_samples", "jsonable", "loads_object", "now_ns", "pack_samples",
    "parse_topic", "quoted", "request_id_of", "samples_topic", "subscription", "topic", "unpack_samples",
]

#: Protocol version carried in every header as ``"v"`` and in the topic prefix ``hw1``.
VERSION = 1
#: The first element of every topic.
TOPIC_PREFIX = f"hw{VERSION}"
#: Message kinds (the third topic element).
KINDS = ("samples", "status", "run", "calib", "baseline", "alarm", "counters", "job")
#: dtype of the power part of a samples payload (little-endian float64).
SAMPLE_DTYPE = "<f8"
#: dtype of the time part of a samples payload (little-endian int64 ns).
TIME_DTYPE = "<i8"

# ----------------------------------------------------------------------------------------------
# Topics


def topic(node: str, kind: str, channel: str | None = None) -> str:
    """The topic of a message: ``hw1/<node>/<kind>`` or ``hw1/<node>/samples/<channel>``.

    Raises:
        ProtocolError: for an unknown kind, a missing channel on samples, or a ``/`` in a name.
    """
    if kind not in KINDS:
        raise ProtocolError(f"topic kind {kind!r}: expected one of {KINDS}")
    _check_name("node", node)
    if kind == "samples":
        if channel is None:
            raise ProtocolError("samples topic needs a channel")
        _check_name("channel", channel)
        return f"{TOPIC_PREFIX}/{node}/samples/{channel}"
    if channel is not None:
        raise ProtocolError(f"{kind} topic takes no channel")
    return f"{TOPIC_PREFIX}/{node}/{kind}"


def samples_topic(node: str, channel: str) -> str:
    """``hw1/<node>/samples/<channel>``."""
    return topic(node, "samples", channel)


def subscription(node: str | None = None, kind: str | None = None) -> bytes:
    """A SUB prefix: everything (``hw1/``), one node (``hw1/n/``) or one kind of one node.

    Note that ``hw1/n1/`` does not match node ``n10`` because of the trailing slash.
    """
    if node is None:
        if kind is not None:
            raise ProtocolError("a kind subscription needs a node (ZeroMQ matches prefixes)")
        return f"{TOPIC_PREFIX}/".encode()
    _check_name("node", node)
    if kind is None:
        return f"{TOPIC_PREFIX}/{node}/".encode()
    if kind not in KINDS:
        raise ProtocolError(f"subscription kind {kind!r}: expected one of {KINDS}")
    suffix = "/" if kind == "samples" else ""
    return f"{TOPIC_PREFIX}/{node}/{kind}{suffix}".encode()


def parse_topic(text: str) -> tuple[str, str, str | None]:
    """Split a topic into ``(node, kind, channel or None)``.

    Raises:
        ProtocolError: when it is not a v1 topic.
    """
    parts = text.split("/")
    if len(parts) < 3 or parts[0] != TOPIC_PREFIX:
        raise ProtocolError(f"topic {text!r}: expected '{TOPIC_PREFIX}/<node>/<kind>[/<channel>]'")
    node, kind = parts[1], parts[2]
    if not node:
        raise ProtocolError(f"topic {text!r}: empty node")
    if kind == "samples":
        if len(parts) != 4 or not parts[3]:
            raise ProtocolError(f"topic {text!r}: samples topics are '{TOPIC_PREFIX}/<node>/samples/<channel>'")
        return node, kind, parts[3]
    if len(parts) != 3:
        raise ProtocolError(f"topic {text!r}: too many elements for kind {kind!r}")
    return node, kind, None


def _check_name(what: str, name: str) -> None:
    if not isinstance(name, str) or not name or "/" in name:
        raise ProtocolError(f"{what} {name!r}: expected a non-empty name without '/'")


# ----------------------------------------------------------------------------------------------
# Stream messages


def now_ns() -> int:
    """Wall-clock time in integer nanoseconds (labels only; never for intervals)."""
    return time.time_ns()


def encode(topic: str | bytes, header: Mapping[str, Any], payload: bytes = b"") -> list[bytes]:
    """The three frames of a stream message. ``"v"`` is filled in when absent.

    Raises:
        ProtocolError: when ``seq``, ``node`` or ``t_ns`` is missing or not an integer/string.
    """
    head = dict(header)
    head.setdefault("v", VERSION)
    _check_header(head, "header")
    topic_bytes = topic.encode() if isinstance(topic, str) else bytes(topic)
    return [topic_bytes, dumps(head), bytes(payload)]


def _check_header(head: Mapping[str, Any], where: str) -> None:
    if head.get("v") != VERSION:
        raise ProtocolError(f"{where}: v = {head.get('v')!r}; expected {VERSION}")
    for key in ("seq", "t_ns"):
        value = head.get(key)
        if isinstance(value, bool) or not isinstance(value, int | np.integer):
            raise ProtocolError(f"{where}.{key} = {value!r}: expected an integer")
    if not isinstance(head.get("node"), str):
        raise ProtocolError(f"{where}.node = {head.get('node')!r}: expected a string")


def pack_samples(t_wall_ns: np.ndarray, power_w: np.ndarray) -> bytes:
    """Samples payload: n int64 LE ns followed by n float64 LE W.

    Raises:
        ProtocolError: when the arrays differ in length or are not one-dimensional.
    """
    t = np.ascontiguousarray(t_wall_ns, dtype=TIME_DTYPE)
    p = np.ascontiguousarray(power_w, dtype=SAMPLE_DTYPE)
    if t.ndim != 1 or p.shape != t.shape:
        raise ProtocolError(f"samples: times {t.shape} and powers {p.shape} must be equal 1-D arrays")
    return b"".join((t.data, p.data))


def unpack_samples(payload: bytes, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`pack_samples` (read-only views on ``payload``).

    Raises:
        ProtocolError: when the payload is not exactly ``16 * n`` bytes.
    """
    if n < 0 or len(payload) != 16 * n:
        raise ProtocolError(f"samples payload: {len(payload)} bytes for n = {n}; expected {16 * n}")
    t = np.frombuffer(payload, dtype=TIME_DTYPE, count=n)
    p = np.frombuffer(payload, dtype=SAMPLE_DTYPE, count=n, offset=8 * n)
    return t, p


_QUOTED: dict[str, str] = {}


def _quoted(text: str) -> str:
    """``text`` as a JSON string literal (memoised: node, channel and status names repeat)."""
    quoted = _QUOTED.get(text)
    if quoted is None:
        quoted = json.dumps(str(text))
        if len(_QUOTED) < 4096:
            _QUOTED[text] = quoted
    return quoted


def _json_number(value: float) -> str:
    value = float(value)
    return repr(value) if math.isfinite(value) else "null"


_TIME = np.dtype(TIME_DTYPE)
_SAMPLE = np.dtype(SAMPLE_DTYPE)


class SamplesEncoder:
    """The one encoder of samples messages: one channel's topic and header, fixed fields formatted once.

    The header is formatted directly (the daemon's hot path: every channel, every poll); it is the
    same JSON object the generic :func:`encode` would produce, in the order of the table in
    ``docs/protocol.md``. :func:`encode_samples` and the daemon's publisher both use it.

    Args:
        node: node name.
        channel: channel name, e.g. ``"DDR_AB"``.
        rate_hz: the channel's native sample rate.

    Raises:
        ProtocolError: a name with ``/`` or an empty one.

    Example:
        >>> enc = SamplesEncoder("n1", "DDR_AB", 100.0)
        >>> frames = enc.frames(0, 5, np.array([10], dtype="<i8"), np.array([2.0]), 1.5, "ok")
        >>> frames[0], json.loads(frames[1])["dt_ns"]
        (b'hw1/n1/samples/DDR_AB', 10000000)
    """

    def __init__(self, node: str, channel: str, rate_hz: float) -> None:
        self.topic = samples_topic(node, channel)
        self.topic_bytes = self.topic.encode()
        self.rate_hz = float(rate_hz)
        rate = self.rate_hz
        dt = str(round(1e9 / rate)) if rate > 0 and math.isfinite(rate) else "null"
        fixed = [x.replace("%", "%%") for x in (_quoted(node), _quoted(channel), _json_number(rate), dt)]
        self._template = (
            '{"v":' + str(VERSION) + ',"seq":%d,"node":' + fixed[0] + ',"t_ns":%d,"channel":' + fixed[1]
            + ',"unit":"W","rate_hz":' + fixed[2] + ',"n":%d,"dtype":"<f8","t0_ns":%s,"dt_ns":' + fixed[3]
            + ',"energy_j":%s,"status":%s}'
        )

    def frames(self, seq: int, t_ns: int, t_wall_ns: np.ndarray, power_w: np.ndarray, energy_j: float,
               status: str) -> list[bytes]:
        """The three frames of one batch (positional: the hot path).

        Args:
            seq: this topic's sequence number.
            t_ns: header time (wall clock, int ns).
            t_wall_ns: sample times (wall clock, int ns).
            power_w: sample values in W (NaN = unknown).
            energy_j: cumulative energy at the end of the batch (NaN = unknown → ``null``).
            status: the channel status (``"ok"``, ``"stale"``, ``"error: ..."``).

        Raises:
            ProtocolError: times and powers of different lengths or not one-dimensional.
        """
        # identity, not equality: the native dtypes are numpy's singletons (any other takes pack_samples)
        if (t_wall_ns.dtype is _TIME and power_w.dtype is _SAMPLE and t_wall_ns.ndim == power_w.ndim == 1
                and len(t_wall_ns) == len(power_w)):
            payload = t_wall_ns.tobytes() + power_w.tobytes()
            n = len(t_wall_ns)
            t0 = str(t_wall_ns.item(0)) if n else "null"
        else:
            payload = pack_samples(t_wall_ns, power_w)
            n = len(payload) >> 4
            t0 = str(int(t_wall_ns[0])) if n else "null"
        energy = float(energy_j)
        header = self._template % (
            int(seq),
            int(t_ns),
            n,
            t0,
            repr(energy) if math.isfinite(energy) else "null",
            _quoted(status),
        )
        return [self.topic_bytes, header.encode(), payload]


def encode_samples(
    node: str,
    channel: str,
    *,
    seq: int,
    rate_hz: float,
    t_wall_ns: np.ndarray,
    power_w: np.ndarray,
    energy_j: float,
    status: str,
    t_ns: int | None = None,
) -> list[bytes]:
    """Frames of one samples batch of one channel (a one-off :class:`SamplesEncoder`).

    Args:
        node: node name.
        channel: channel name, e.g. ``"DDR_AB"``.
        seq: this topic's sequence number.
        rate_hz: the channel's native sample rate.
        t_wall_ns: sample times (wall clock, int ns).
        power_w: sample values in W (NaN = unknown).
        energy_j: cumulative energy at the end of the batch (NaN = unknown → ``null``).
        status: the channel status (``"ok"``, ``"stale"``, ``"error: ..."``).
        t_ns: header time; defaults to now.
    """
    encoder = SamplesEncoder(node, channel, rate_hz)
    return encoder.frames(seq, now_ns() if t_ns is None else int(t_ns), np.asarray(t_wall_ns), np.asarray(power_w),
                          energy_j, status)


@dataclass(frozen=True)
class Message:
    """A decoded stream message.

    Attributes:
        topic: the topic string.
        kind: ``samples``, ``status``, ``run``, ``calib``, ``baseline`` (or a newer kind).
        node: the node name.
        channel: the channel for samples, else None.
        header: the parsed header (NaN arrives as None).
        payload: the raw payload bytes.
    """

    topic: str
    kind: str
    node: str
    channel: str | None
    header: dict[str, Any]
    payload: bytes = field(repr=False)

    @property
    def seq(self) -> int:
        """The header's sequence number."""
        return int(self.header["seq"])

    @property
    def t_ns(self) -> int:
        """The header's wall-clock time in ns."""
        return int(self.header["t_ns"])

    def samples(self) -> tuple[np.ndarray, np.ndarray]:
        """``(t_wall_ns int64, power_w float64)`` of a samples message.

        Raises:
            ProtocolError: when this is not a samples message.
        """
        if self.kind != "samples":
            raise ProtocolError(f"{self.topic}: not a samples message")
        return unpack_samples(self.payload, int(self.header["n"]))


def decode(frames: Sequence[bytes | Any]) -> Message:
    """Decode the frames of a stream message (bytes or ``zmq.Frame``).

    Raises:
        ProtocolError: wrong frame count, non-v1 topic or header, or a samples payload whose size
            does not match its header.
    """
    if len(frames) != 3:
        raise ProtocolError(f"expected 3 frames [topic, header, payload], got {len(frames)}")
    raw = [f if isinstance(f, bytes) else bytes(f.buffer if hasattr(f, "buffer") else f) for f in frames]
    try:
        topic_text = raw[0].decode("utf-8")
    except UnicodeDecodeError:
        raise ProtocolError("topic is not UTF-8") from None
    node, kind, channel = parse_topic(topic_text)
    header = loads_object(raw[1], f"{topic_text} header")
    _check_header(header, f"{topic_text} header")
    if header["node"] != node:
        raise ProtocolError(f"{topic_text}: header node {header['node']!r} differs from the topic")
    if kind == "samples":
        n = header.get("n")
        if isinstance(n, bool) or not isinstance(n, int):
            raise ProtocolError(f"{topic_text}: header n = {n!r}; expected an integer")
        if header.get("dtype", SAMPLE_DTYPE) != SAMPLE_DTYPE:
            raise ProtocolError(f"{topic_text}: dtype {header.get('dtype')!r}; expected {SAMPLE_DTYPE!r}")
        if len(raw[2]) != 16 * n:
            raise ProtocolError(f"{topic_text}: payload {len(raw[2])} bytes for n = {n}; expected {16 * n}")
    return Message(topic=topic_text, kind=kind, node=node, channel=channel, header=header, payload=raw[2])


class SequenceCounter:
    """Per-topic sequence numbers for a publisher (first message of each topic has seq 0)."""

    def __init__(self) -> None:
        self._next: dict[str, int] = {}

    def next(self, topic: str) -> int:
        """The sequence number for the next message on ``topic``."""
        seq = self._next.get(topic, 0)
        self._next[topic] = seq + 1
        return seq


class GapTracker:
    """Counts messages a subscriber missed, from the per-topic sequence numbers (the one gap
    tracker: every subscriber and the TUI's model use it).

    A sequence number that does not go up on a topic means its daemon restarted: counted once in
    :attr:`restarts` (not as a gap), and that node's sequences start afresh. After a silence longer
    than ``silence_ns`` a node's next jump on each topic is not counted as loss (the silence
    showed); a sequence gone back is still a restart.

    Args:
        silence_ns: silence (by the ``now_ns`` given to :meth:`observe`) after which a node's
            sequences start afresh; None: never.

    Example:
        >>> tracker = GapTracker()
        >>> tracker.observe("hw1/n1/status", 0), tracker.observe("hw1/n1/status", 1), tracker.observe("hw1/n1/status", 4)
        (0, 0, 2)
        >>> tracker.missed
        2
    """

    def __init__(self, silence_ns: int | None = None) -> None:
        self.silence_ns = silence_ns
        self._last: dict[str, dict[str, int]] = {}  # node prefix -> topic -> last seq
        self._heard: dict[str, int] = {}  # node prefix -> when it was last heard (now_ns)
        self._after_silence: dict[str, set[str]] = {}  # node prefix -> topics whose next jump is no loss
        self.missed = 0
        self.restarts = 0

    def observe(self, topic: str, seq: int, now_ns: int | None = None) -> int:
        """Record ``seq`` on ``topic`` (received at ``now_ns``, monotonic, when known); return how
        many messages were missed just before it."""
        node = _node_of(topic)
        if now_ns is not None:
            heard = self._heard.get(node)
            self._heard[node] = now_ns
            if heard is not None and self.silence_ns is not None and now_ns - heard > self.silence_ns:
                self._after_silence[node] = set(self._last.get(node, ()))
        seqs = self._last.setdefault(node, {})
        last = seqs.get(topic)
        seqs[topic] = seq
        excused = False
        silent = self._after_silence.get(node)
        if silent is not None and topic in silent:
            silent.discard(topic)
            excused = True
        if last is None:
            return 0
        if seq <= last:
            self.restart(topic)
            return 0
        if excused:
            return 0
        missed = seq - last - 1
        self.missed += missed
        return missed

    def restart(self, topic: str | None = None) -> None:
        """Count a restart of the daemon of ``topic`` (None: of every node, e.g. told by its start
        time) and start its sequences afresh from ``topic``'s latest."""
        self.restarts += 1
        if topic is None:
            self._last.clear()
            self._after_silence.clear()
            return
        node = _node_of(topic)
        seqs = self._last.get(node, {})
        self._last[node] = {topic: seqs[topic]} if topic in seqs else {}
        self._after_silence.pop(node, None)


def _node_of(topic: str) -> str:
    """The ``hw1/<node>`` part of a topic (a topic of fewer parts is its own node)."""
    return "/".join(topic.split("/", 2)[:2])
