"""#13: one samples encoder, owned by the protocol module; no private pyzmq API in the stream/control layer."""

from __future__ import annotations

from pathlib import Path

DAEMON = Path(__file__).resolve().parents[2] / "src" / "hdeem_watch" / "daemon"
#: The wire and socket modules (service.py's poll loop is checked by its own owner's tests).
WIRE_MODULES = ("protocol", "wire", "requests", "publisher", "control", "client", "endpoints", "security", "store")


def test_no_private_pyzmq_api_and_one_samples_encoder() -> None:
    """No ``zmq.backend`` in the wire modules; nobody but protocol.py formats samples headers."""
    for name in WIRE_MODULES:
        text = (DAEMON / f"{name}.py").read_text()
        assert "zmq.backend" not in text, name
        if name != "protocol":
            assert "protocol._quoted" not in text and '"unit":"W"' not in text, name
