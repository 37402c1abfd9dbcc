"""The one subscriber core (issue #26): discovery, late join, reconnect and gap tracking decided
without sockets, on a fake clock, for the TUI's thread and MetricQ's asyncio reader alike."""

from __future__ import annotations

import numpy as np

from hdeem_watch.wire import protocol
from hdeem_watch.wire.subscriber import LATE_JOIN_OPS, StreamFollower

S = 1_000_000_000
CONTROL = "ipc:///run/hw/control.sock"


def _status(pub: str = "ipc:///run/hw/pub.sock", node: str = "n1", **endpoints: object) -> dict[str, object]:
    return {"node": node, "endpoints": {"pub": pub, "control": CONTROL, **endpoints}}


def _samples(node: str, seq: int, channel: str = "DDR_AB") -> list[bytes]:
    return protocol.encode_samples(node, channel, seq=seq, rate_hz=100.0, t_wall_ns=np.array([seq]),
                                   power_w=np.array([1.0]), energy_j=1.0, status="ok")


def _status_message(node: str, seq: int) -> list[bytes]:
    return protocol.encode(protocol.topic(node, "status"), {"seq": seq, "node": node, "t_ns": 1})


def test_first_status_subscribes_to_the_node_and_late_joins_as_history() -> None:
    follower = StreamFollower(CONTROL)
    assert follower.probe_due(0, subscribed=False)
    plan = follower.plan(_status(), 0, subscribed=False)
    assert plan.subscribe == "ipc:///run/hw/pub.sock" and plan.subscription == b"hw1/n1/"
    assert plan.late_join and plan.history and not plan.close
    assert LATE_JOIN_OPS == ("runs.list", "calib.get", "baseline.get")
    # the same status again: nothing to do
    again = follower.plan(_status(), S, subscribed=True)
    assert again.subscribe is None and not again.late_join


def test_probes_are_spaced_and_stop_while_the_stream_flows() -> None:
    follower = StreamFollower(CONTROL, stale_after_ns=3 * S)
    assert follower.probe_due(0, subscribed=False)
    assert not follower.probe_due(S // 2, subscribed=False)  # at most one a second
    assert follower.probe_due(S, subscribed=False)
    follower.plan(_status(), S, subscribed=False)
    assert follower.accept(_samples("n1", 0), S) is not None
    assert not follower.probe_due(3 * S, subscribed=True)  # the stream flows
    assert follower.probe_due(5 * S, subscribed=True)  # quiet for more than 3 s: ask the daemon


def test_reconnect_late_joins_again_not_as_history_and_follows_a_moved_stream() -> None:
    follower = StreamFollower(CONTROL)
    follower.plan(_status(), 0, subscribed=False)
    lost = follower.unreachable("connection refused", state="live", subscribed=True)
    assert (lost.state, lost.detail) == ("reconnecting", "connection refused")
    back = follower.plan(_status("ipc:///run/hw/pub2.sock"), 2 * S, subscribed=True)
    assert back.late_join and not back.history
    assert back.subscribe == "ipc:///run/hw/pub2.sock"
    shown = follower.connection(back, 2 * S, state="reconnecting", refused=None)
    assert shown is not None and shown.detail == "daemon back; waiting for its stream"


def test_before_first_contact_an_unreachable_daemon_is_connecting() -> None:
    follower = StreamFollower(CONTROL)
    assert follower.unreachable("timeout", state="connecting", subscribed=False).state == "connecting"


def test_an_ipc_stream_of_another_host_is_named_unreachable_not_waited_for() -> None:
    follower = StreamFollower("tcp://node7:5591", is_local=lambda host: False)
    plan = follower.plan(_status("ipc:///run/hw/pub.sock"), 0, subscribed=False)
    assert plan.close and plan.subscribe is None
    shown = follower.connection(plan, 0, state="connecting", refused=None)
    assert shown is not None and "reachable only on node7" in shown.detail
    # the daemon advertises a remote stream: taken, with the wildcard host replaced
    remote = follower.plan(_status("ipc:///run/hw/pub.sock", remote={"pub": "tcp://*:5590"}), S, subscribed=False)
    assert remote.subscribe == "tcp://node7:5590" and not remote.close


def test_a_stream_that_stays_silent_after_subscribing_is_reported() -> None:
    follower = StreamFollower(CONTROL, stale_after_ns=3 * S)
    plan = follower.plan(_status(), 0, subscribed=False)
    assert follower.connection(plan, S, state="connecting", refused=None) is None
    later = follower.plan(_status(), 4 * S, subscribed=True)
    shown = follower.connection(later, 4 * S, state="connecting", refused=None)
    assert shown is not None and "nothing arrives from its stream" in shown.detail
    refused = follower.connection(later, 4 * S, state="connecting", refused="key not registered")
    assert refused is not None and refused.detail.endswith("refused: key not registered")


def test_gaps_count_missed_messages_and_a_restart_once() -> None:
    follower = StreamFollower(None)
    for seq in (0, 1, 4):
        follower.accept(_samples("n1", seq), 0)
    assert follower.gaps.missed == 2
    follower.accept(_status_message("n1", 7), 0)
    # the daemon restarts: every topic starts again at 0, counted once, not as gaps
    assert follower.accept(_samples("n1", 0), 0) is not None
    follower.accept(_status_message("n1", 0), 0)
    follower.accept(_samples("n1", 1), 0)
    assert (follower.gaps.missed, follower.gaps.restarts) == (2, 1)


def test_a_restart_of_one_node_keeps_the_gap_count_of_another() -> None:
    follower = StreamFollower(None)
    follower.accept(_samples("n1", 5), 0)
    follower.accept(_samples("n2", 5), 0)
    follower.accept(_samples("n1", 0), 0)  # n1 restarted
    follower.accept(_samples("n2", 8), 0)  # n2 missed two
    assert (follower.gaps.missed, follower.gaps.restarts) == (2, 1)


def test_a_jump_across_a_silence_is_not_loss() -> None:
    follower = StreamFollower(None, stale_after_ns=3 * S)
    follower.accept(_samples("n1", 0), 0)
    follower.accept(_samples("n1", 100), 10 * S)  # the silence showed already
    follower.accept(_samples("n1", 103), 10 * S + 1)
    assert follower.gaps.missed == 2


def test_kinds_not_taken_are_dropped_before_decoding_and_bad_frames_counted() -> None:
    follower = StreamFollower(None, kinds=("samples",))
    assert follower.accept(_status_message("n1", 0), 0) is None
    assert follower.bad_messages == 0 and follower.messages == 0
    assert follower.accept([b"hw1/n1/samples/DDR_AB", b"{not json", b""], 0) is None
    assert follower.bad_messages == 1 and "header" in follower.last_error
    message = follower.accept(_samples("n1", 0), 5)
    assert message is not None and message.channel == "DDR_AB" and follower.last_rx_ns == 5


def test_without_a_control_endpoint_there_is_nothing_to_probe() -> None:
    assert not StreamFollower(None).probe_due(0, subscribed=False)


def test_a_restart_during_a_silence_is_still_a_restart() -> None:
    """The daemon stops (silence), then starts again: its sequences went back; a restart, no loss."""
    follower = StreamFollower(None, stale_after_ns=3 * S)
    for seq in (40, 41):
        follower.accept(_samples("n1", seq), 0)
    follower.accept(_samples("n1", 0), 10 * S)
    follower.accept(_samples("n1", 1), 10 * S + 1)
    assert (follower.gaps.missed, follower.gaps.restarts) == (0, 1)
