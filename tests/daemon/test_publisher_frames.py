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
