"""#13: one samples encoder, owned by the protocol module; no private pyzmq API in the stream/control layer."""

from __future__ import annotations

from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[2] / "src" / "hdeem_watch"
#: The wire and socket modules: the whole wire package and the daemon's socket side (service.py's
#: poll loop is checked by its own owner's tests).
WIRE_MODULES = (*sorted(str(p.relative_to(PACKAGE).with_suffix("")) for p in (PACKAGE / "wire").glob("*.py")),
                "daemon/shell/publisher", "daemon/shell/control", "daemon/shell/endpoints", "daemon/shell/security",
                "daemon/store/database")


def test_no_private_pyzmq_api_and_one_samples_encoder() -> None:
    """No ``zmq.backend`` in the wire modules; nobody but wire/protocol.py formats samples headers."""
    assert "wire/protocol" in WIRE_MODULES and "wire/subscriber" in WIRE_MODULES
    for name in WIRE_MODULES:
        text = (PACKAGE / f"{name}.py").read_text()
        assert "zmq.backend" not in text, name
        if name != "wire/protocol":
            assert "protocol._quoted" not in text and '"unit":"W"' not in text, name
