"""``calib.get`` under a crowd: the sim's truth is computed at most once per second of source time and
the reply is encoded once per calibration body and truth (each was ~1 ms of the loop per request).

Run on the pure run book with a fake clock and a source that counts its truth computations.
"""

from __future__ import annotations

from typing import Any

import pytest

from hdeem_watch.daemon.book.state import NodeState
from hdeem_watch.daemon.ops.reporting import TRUTH_MAX_AGE_S, Identity, Reporter
from hdeem_watch.daemon.shell.workers import Calibration
from hdeem_watch.sources.base import ChannelInfo
from hdeem_watch.wire.protocol import EncodedResult, decode_reply, encode_reply_ok


class TruthfulSource:
    """A simulated source whose hidden truth is its clock's reading (and counts how often it was asked)."""

    kind = "sim"

    def __init__(self, clock: list[int]) -> None:
        self.clock = clock
        self.computed = 0

    def truth(self) -> dict[str, Any]:
        self.computed += 1
        return {"simulated": True, "t_ns": self.clock[0], "currents": {"IDD0": 0.05 + self.clock[0] * 1e-15}}

    def health(self) -> str:
        return "ok"


class NoPublisher:
    def publish(self, kind: str, body: Any, **_: Any) -> bool:
        return True


def reporter_of(source: Any, calibration: Calibration, clock: list[int], speed: float) -> Reporter:
    book = NodeState([ChannelInfo("DDR_AB", 100.0, "dram")], node="n1", monotonic=lambda: clock[0],
                     wall=lambda: clock[0], speed=speed)
    return Reporter(book, calibration, source, NoPublisher(), store=None,  # type: ignore[arg-type]
                    identity=Identity("sim", {}), poll_interval_ns=lambda: 40_000_000, clock=lambda: clock[0])


@pytest.mark.parametrize("speed", [1.0, 10.0])
def test_the_truth_is_computed_once_per_second_of_source_time_and_the_reply_encoded_once(speed: float) -> None:
    clock = [5_000_000_000]
    source = TruthfulSource(clock)
    calibration = Calibration()
    calibration.body = {"fit": {"n_runs": 3, "currents": {"IDD0": 0.051}}, "runs": 3}
    reporter = reporter_of(source, calibration, clock, speed)
    age_ns = round(TRUTH_MAX_AGE_S * 1e9 / speed)  # one second of source time on the daemon's clock

    first = reporter.calib_reply()
    for _ in range(50):  # a crowd within the same second: one truth, one encoding
        clock[0] += age_ns // 100
        assert reporter.calib_reply() is first
    assert source.computed == 1
    truth = {"simulated": True, "t_ns": 5_000_000_000, "currents": {"IDD0": 0.05 + 5e9 * 1e-15}}
    assert first.decoded() == {**calibration.body, "truth": truth}
    # A client reads the bytes the uncached reply would have had.
    assert encode_reply_ok(7, first) == encode_reply_ok(7, {**calibration.body, "truth": truth})
    assert decode_reply(encode_reply_ok(7, first)).result == first.decoded()

    clock[0] = 5_000_000_000 + age_ns  # a second of source time later: the truth of now
    later = reporter.calib_reply()
    assert source.computed == 2 and later is not first
    assert later.decoded()["truth"]["t_ns"] == clock[0]

    calibration.body = {"fit": {"n_runs": 4, "currents": {"IDD0": 0.049}}, "runs": 4}  # a refit
    refit = reporter.calib_reply()
    assert source.computed == 2, "a new calibration does not compute the truth again"
    assert refit.decoded()["fit"]["n_runs"] == 4 and refit.decoded()["truth"]["t_ns"] == clock[0]
    assert reporter.calib_with_truth() == refit.decoded()  # the published body says the same


def test_real_sensors_have_no_truth() -> None:
    class Hdeem:
        kind = "hdeem"

        def health(self) -> str:
            return "ok"

    clock = [0]
    calibration = Calibration()
    calibration.body = {"fit": None}
    reply = reporter_of(Hdeem(), calibration, clock, 1.0).calib_reply()
    assert isinstance(reply, EncodedResult) and reply.decoded() == {"fit": None, "truth": None}
