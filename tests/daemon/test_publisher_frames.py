"""The publisher's pre-formatted samples headers are exactly the protocol's samples messages."""

from __future__ import annotations

import math

import numpy as np
import pytest
import zmq

from hdeem_watch.daemon.shell.publisher import Publisher
from hdeem_watch.wire import protocol


@pytest.mark.parametrize(("channel", "rate_hz", "n", "energy_j", "status"), [
    ("BLADE", 1000.0, 25, 1234.5, "ok"),
    ("DDR_AB", 100.0, 0, math.nan, 'error: odd "%s" 100%'),
    ("CPU0", 0.0, 1, 1e300, "gap"),
    ("DRAM1", 3.3, 3, -0.0, "stale"),
])
def test_template_frames_equal_encode_samples(channel, rate_hz, n, energy_j, status) -> None:
    """Frames from the per-channel header template equal protocol.encode_samples (bytes), sequence numbers
    count per topic, and a changed rate gives a new template."""
    pub = Publisher(zmq.Context.instance(), f"inproc://frames-{channel}", node="node%1")
    try:
        t_ns = np.arange(n, dtype=np.int64) * 1_000_000 + 1_700_000_000_000_000_000
        power_w = np.linspace(0.0, 5.0, n)
        for seq, rate in enumerate((rate_hz, rate_hz, rate_hz * 2)):
            got = pub.samples_message(channel, rate, t_ns, power_w, energy_j, status, 42)
            want = protocol.encode_samples("node%1", channel, seq=seq, rate_hz=rate, t_wall_ns=t_ns, power_w=power_w,
                                           energy_j=energy_j, status=status, t_ns=42)
            assert got == want
            assert protocol.decode(got).header["n"] == n
    finally:
        pub.close()


@pytest.mark.parametrize(("time_dtype", "power_dtype"), [(">i8", "<f8"), ("<i8", ">f8"), ("<i4", "<f4"),
                                                          ("<u8", "<f8")])
def test_times_and_powers_of_other_dtypes_give_the_native_frames(time_dtype: str, power_dtype: str) -> None:
    """The encoder's fast path takes only native int64 times and float64 powers; any other dtype is
    converted on the general path, to the same bytes."""
    encoder = protocol.SamplesEncoder("n1", "DDR_AB", 100.0)
    t_ns = np.arange(4, dtype=np.int64) * 10_000_000 + 1_000_000_000
    power_w = np.array([1.5, 2.0, 2.5, 3.0])
    want = encoder.frames(7, 42, t_ns, power_w, 3.0, "ok")
    got = encoder.frames(7, 42, t_ns.astype(time_dtype), power_w.astype(power_dtype), 3.0, "ok")
    assert got == want


def test_times_and_powers_of_different_lengths_or_shapes_are_refused() -> None:
    encoder = protocol.SamplesEncoder("n1", "DDR_AB", 100.0)
    t_ns = np.arange(4, dtype=np.int64)
    with pytest.raises(protocol.ProtocolError):
        encoder.frames(0, 0, t_ns, np.zeros(3), 0.0, "ok")
    with pytest.raises(protocol.ProtocolError):
        encoder.frames(0, 0, t_ns, np.zeros((4, 1)), 0.0, "ok")
