"""DRAM command rates in the TUI (issue 17): the ``counters`` topic → each DRAM channel's ACT/s, RD/s,
WR/s and power-down share beside its power; unknown shown as "–", stale rates not shown."""

from __future__ import annotations

import math

import numpy as np

from hdeem_watch.tui.model import NodeModel
from hdeem_watch.tui.widgets.channels import channel_table_text
from hdeem_watch.wire import protocol

SECOND = 1_000_000_000


def samples(channel: str, seq: int) -> protocol.Message:
    frames = protocol.encode_samples("n1", channel, seq=seq, rate_hz=100.0, t_wall_ns=np.array([0, 10_000_000]),
                                     power_w=np.array([5.0, 7.0]), energy_j=1.0, status="ok", t_ns=10_000_000)
    return protocol.decode(frames)


def counters(seq: int, rd_per_s: float | None) -> protocol.Message:
    body = {"source": "sim", "generation": "haswell-ep", "status": "ok", "channels": {
        "S0.imc0": {"act_per_s": 2e6, "rd_per_s": rd_per_s, "wr_per_s": 1e8, "powerdown_share": 0.2, "sensor": "DDR_AB"},
        "S0.imc1": {"act_per_s": 3e6, "rd_per_s": 5e8, "wr_per_s": 2e8, "powerdown_share": 0.4, "sensor": "DDR_AB"}}}
    return protocol.decode(protocol.encode(protocol.topic("n1", "counters"), {"seq": seq, "node": "n1", "t_ns": 0,
                                                                          **body}))


def snapshot(model: NodeModel, now_ns: int):
    return model.snapshot(now_mono_ns=now_ns, now_wall_ns=20_000_000, window_s=1.0, width=4)


def test_rates_appear_beside_the_power_of_the_sensor_they_belong_to() -> None:
    model = NodeModel(endpoint="ipc:///x")
    model.apply(samples("DDR_AB", 0), recv_mono_ns=0)
    model.apply(samples("CPU0", 0), recv_mono_ns=0)
    model.apply(counters(0, 3e8), recv_mono_ns=0)
    snap = snapshot(model, 0)
    dram = next(c for c in snap.channels if c.name == "DDR_AB")
    cpu = next(c for c in snap.channels if c.name == "CPU0")
    assert dram.commands is not None and cpu.commands is None
    assert (dram.commands.act_per_s, dram.commands.rd_per_s, dram.commands.wr_per_s) == (5e6, 8e8, 3e8)
    assert math.isclose(dram.commands.powerdown_share, 0.3)
    wide = channel_table_text(snap, 100).plain
    assert "ACT/s" in wide and "5.00M" in wide and "800M" in wide and "30%" in wide
    assert "ACT/s" not in channel_table_text(snap, 60).plain  # no room: the power table as before


def test_an_unknown_rate_is_a_dash_and_old_rates_disappear() -> None:
    model = NodeModel(endpoint="ipc:///x", stale_after_s=3.0)
    model.apply(samples("DDR_AB", 0), recv_mono_ns=0)
    model.apply(counters(0, None), recv_mono_ns=0)
    line = next(row for row in channel_table_text(snapshot(model, 0), 100).plain.splitlines() if row.startswith("DDR_AB"))
    assert "–" in line.split("ok")[-1]
    model.apply(samples("DDR_AB", 1), recv_mono_ns=10 * SECOND)  # samples go on, counters stopped
    assert next(c for c in snapshot(model, 10 * SECOND).channels if c.name == "DDR_AB").commands is None
