"""The feed thread over real ZeroMQ sockets (ipc), against a small wire-protocol publisher."""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from hdeem_watch.demo.fakenode import FakeNode
from hdeem_watch.tui.feed import FeedHub, NodeFeed
from hdeem_watch.tui.messages import ViewSettings
from hdeem_watch.tui.model import NodeModel
from hdeem_watch.tui.snapshot import NodeSnapshot
from hdeem_watch.wire.discovery import pub_endpoint_for, stream_endpoint, unreachable_stream


def wait_for(feed: NodeFeed, cond: Callable[[NodeSnapshot], bool], timeout_s: float = 8.0) -> NodeSnapshot:
    """The first snapshot satisfying ``cond`` (fails with the last one otherwise)."""
    deadline = time.monotonic() + timeout_s
    snap = feed.latest
    while time.monotonic() < deadline:
        snap = feed.latest
        if cond(snap):
            return snap
        time.sleep(0.05)
    raise AssertionError(f"condition not met within {timeout_s} s; last health: {snap.health}")


@pytest.mark.slow
def test_feed_learns_stream_endpoint_and_values_update(fake_node: FakeNode) -> None:
    """From only the control endpoint the feed finds the stream, and the DRAM values change over time."""
    feed = NodeFeed(fake_node.control_endpoint, view=ViewSettings(window_s=5, width=40))
    feed.start()
    try:
        first = wait_for(feed, lambda s: s.health.state == "live" and len(s.channels) == 7)
        assert first.node == "fake1" and first.health.source_kind == "fake"
        assert [c.name for c in first.channels][:4] == ["DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH"]
        time.sleep(0.6)
        later = wait_for(feed, lambda s: s.built_mono_ns > first.built_mono_ns)
        assert any(a.power_w != b.power_w for a, b in zip(first.channels, later.channels))
        blade = next(c for c in later.channels if c.name == "BLADE")
        assert blade.rate_hz == 1000.0 and blade.columns is not None and blade.columns.width == 40
    finally:
        feed.stop()


@pytest.mark.slow
def test_feed_counts_wire_gaps(fake_node: FakeNode) -> None:
    """Messages the publisher skips (sequence numbers jump) show up as gaps in the health view."""
    feed = NodeFeed(fake_node.control_endpoint)
    feed.start()
    try:
        # A gap is countable only on a topic the feed has already seen: wait for every channel and
        # for a status heartbeat (published once a second), else a skipped number can be the
        # first the feed sees of its topic (it failed that way about once in 15 full runs).
        wait_for(feed, lambda s: s.health.state == "live" and len(s.channels) == 7)
        time.sleep(1.2)
        assert feed.latest.health.gaps == 0
        fake_node.skip_seq = 3
        snap = wait_for(feed, lambda s: s.health.gaps >= 3)
        assert snap.health.gaps == 3
    finally:
        feed.stop()


@pytest.mark.slow
def test_feed_goes_stale_then_reconnects_to_a_restarted_daemon(sock_dir: Path) -> None:
    """A vanished daemon turns the node stale/reconnecting; a new one on the same endpoints is picked up again."""
    pub, ctl = f"ipc://{sock_dir}/r-pub", f"ipc://{sock_dir}/r-ctl"
    node = FakeNode("rn", pub, ctl).start_and_wait()
    feed = NodeFeed(ctl, stale_after_s=1.0, control_timeout_s=0.3)
    feed.start()
    try:
        wait_for(feed, lambda s: s.health.state == "live")
        node.stop()
        (sock_dir / "r-ctl").unlink(missing_ok=True)
        down = wait_for(feed, lambda s: s.health.state in ("stale", "reconnecting"))
        wait_for(feed, lambda s: s.health.state == "reconnecting")
        assert down.health.state != "live"
        node = FakeNode("rn", pub, ctl).start_and_wait()
        back = wait_for(feed, lambda s: s.health.state == "live" and s.health.restarts >= 1)
        assert back.health.restarts == 1 and back.health.last_rx_age_s < 1.0
    finally:
        feed.stop()
        node.stop()


@pytest.mark.slow
def test_control_request_reaches_daemon_and_notice_shows_reply(fake_node: FakeNode) -> None:
    """A UI request (baseline.measure) is sent by the feed's thread; the reply and the new baseline show up."""
    hub = FeedHub([fake_node.control_endpoint])
    hub.start()
    try:
        wait_for(hub.feeds[0], lambda s: s.health.state == "live")
        hub.request(0, "baseline.measure", {"seconds": 2.0})
        snap = wait_for(hub.feeds[0], lambda s: "baseline.measure: ok" in s.health.notice)
        assert ("baseline.measure", {"seconds": 2.0}) in fake_node.requests
        snap = wait_for(hub.feeds[0], lambda s: all(c.baseline_w == c.baseline_w for c in s.channels))
        assert snap.channels[0].baseline_w == 6.0
    finally:
        hub.stop()


def test_wildcard_pub_endpoint_uses_control_host() -> None:
    """A daemon bound to tcp://*:port is reached at the host of its control endpoint."""
    assert pub_endpoint_for("tcp://node7:5591", "tcp://*:5590") == "tcp://node7:5590"
    assert pub_endpoint_for("tcp://node7:5591", "tcp://10.0.0.7:5590") == "tcp://10.0.0.7:5590"
    assert pub_endpoint_for("ipc:///a", "ipc:///b") == "ipc:///b"


def test_a_remote_client_takes_the_advertised_tcp_stream() -> None:
    """From another host the advertised ``endpoints.remote.pub`` replaces an ipc stream; on the
    daemon's own host the local one is used."""
    endpoints = {"pub": "ipc:///run/hdeem-watch/pub.sock", "remote": {"pub": "tcp://node7:5590", "control": None}}
    assert stream_endpoint("tcp://node7:5591", endpoints, is_local=lambda host: False) == "tcp://node7:5590"
    assert stream_endpoint("tcp://node7:5591", endpoints, is_local=lambda host: True) == "ipc:///run/hdeem-watch/pub.sock"
    assert stream_endpoint("tcp://node7:5591", {"pub": "tcp://*:5590"}, is_local=lambda host: False) == "tcp://node7:5590"
    assert stream_endpoint("tcp://node7:5591", {}, is_local=lambda host: False) == ""


@pytest.mark.slow
def test_a_malformed_message_does_not_end_the_feed(fake_node: FakeNode) -> None:
    """Garbage and protocol-valid but nonsensical messages are counted and skipped; the feed goes on."""
    from hdeem_watch.wire import protocol

    feed = NodeFeed(fake_node.control_endpoint)
    feed.start()
    try:
        wait_for(feed, lambda s: s.health.state == "live")
        fake_node.inject([b"hw1/fake1/status", b"not json", b""])
        fake_node.inject([b"hw1/fake1/samples/DDR_AB", b'{"v":1,"seq":0,"node":"fake1","t_ns":0,"n":3}', b"x"])
        fake_node.inject(protocol.encode(protocol.topic("fake1", "run"), {"seq": 0, "node": "fake1", "t_ns": 0,
                                                                           "event": "stop", "run": {"threads": "many"}}))
        wait_for(feed, lambda s: feed.decode_errors >= 2)
        count = feed.messages
        snap = wait_for(feed, lambda s: feed.messages > count + 20)
        assert feed.is_alive() and snap.health.state == "live"
    finally:
        feed.stop()


@pytest.mark.slow
def test_an_ipc_stream_behind_a_remote_control_endpoint_is_named_unreachable(sock_dir: Path) -> None:
    """A daemon reached over TCP from another host whose stream is ipc: the feed says why within
    seconds instead of waiting at "connecting" forever."""
    node = FakeNode("remote1", f"ipc://{sock_dir}/r-pub", "tcp://127.0.0.1:*").start_and_wait()
    feed = NodeFeed(node.control_endpoint, is_local=lambda host: False)  # as seen from another host
    feed.start()
    try:
        snap = wait_for(feed, lambda s: "reachable only on 127.0.0.1" in s.health.detail, timeout_s=5.0)
        assert snap.health.state == "connecting"
        assert "--pub tcp://*:PORT" in snap.health.detail
    finally:
        feed.stop()
        node.stop()


def test_unreachable_stream_rules() -> None:
    """Only an ipc stream behind a TCP control endpoint of another host is unreachable."""
    remote = {"is_local": lambda host: False}
    assert unreachable_stream("tcp://node7:5591", "ipc:///x/pub.sock", **remote) is not None
    assert unreachable_stream("tcp://node7:5591", "tcp://node7:5590", **remote) is None
    assert unreachable_stream("ipc:///x/control.sock", "ipc:///x/pub.sock", **remote) is None
    assert unreachable_stream("tcp://127.0.0.1:5591", "ipc:///x/pub.sock") is None
    assert unreachable_stream("tcp://localhost:5591", "ipc:///x/pub.sock") is None


@pytest.mark.slow
def test_request_outcomes_reach_the_model_only_on_the_feed_thread(fake_node: FakeNode) -> None:
    """The notice of a control request is written by the feed thread (the model's owner), from a
    message queued by the request thread; neither the app's thread nor the request thread touch it."""
    writers: list[int] = []

    class WatchedModel(NodeModel):
        @property
        def notice(self) -> str:
            return self._notice

        @notice.setter
        def notice(self, value: str) -> None:
            writers.append(threading.get_ident())
            self._notice = value

    feed = NodeFeed(fake_node.control_endpoint)
    feed.model = WatchedModel(fake_node.control_endpoint)
    writers.clear()
    feed.start()
    try:
        wait_for(feed, lambda s: s.health.state == "live")
        feed.request("baseline.measure", {"seconds": 0.2})
        wait_for(feed, lambda s: s.health.notice.startswith("baseline.measure: ok"))
        assert writers and set(writers) == {feed.ident}
    finally:
        feed.stop()


def test_view_settings_are_immutable_and_swapped_whole(fake_node: FakeNode) -> None:
    """The hub gives every feed a new ViewSettings; nobody mutates one in place."""
    hub = FeedHub([fake_node.control_endpoint, fake_node.control_endpoint])
    before = hub.view
    hub.set_view(focus=1, window_s=30.0, width=64)
    assert before == ViewSettings() and hub.view == ViewSettings(window_s=30.0, width=64, focus=1)
    assert all(feed.view is hub.view for feed in hub.feeds)
    with pytest.raises(dataclasses.FrozenInstanceError):
        hub.view.focus = 0  # type: ignore[misc]


@pytest.mark.slow
def test_a_curve_stream_without_the_key_is_named_refused(sock_dir: Path) -> None:
    """A daemon whose control is local ipc and whose stream is CURVE TCP: a feed without the key
    reaches the control socket, and says the stream refused it (not "nothing arrives ... firewall?");
    with the key the same feed goes live."""
    import threading as _threading

    from hdeem_watch.config import DaemonSettings
    from hdeem_watch.daemon.shell.service import Daemon
    from hdeem_watch.sources.sim import SimSource
    from hdeem_watch.wire.keys import client_curve, generate_keys

    public, secret = generate_keys(sock_dir / "keys", "server")
    settings = DaemonSettings(pub="tcp://127.0.0.1:*", control=f"ipc://{sock_dir}/c.sock", node="curve1",
                              state_dir=str(sock_dir / "state"), speed=10.0, curve_secret_key_file=str(secret))
    daemon = Daemon(settings, source=SimSource(seed=1, speed=10.0))
    daemon.start()
    loop = _threading.Thread(target=daemon.run)
    loop.start()
    feeds: list[NodeFeed] = []
    try:
        plain = NodeFeed(daemon.control_endpoint, stale_after_s=1.0)
        feeds.append(plain)
        plain.start()
        snap = wait_for(plain, lambda s: "refused" in s.health.detail)
        assert "requires CURVE" in snap.health.detail and snap.health.state == "connecting"
        keyed = NodeFeed(daemon.control_endpoint, curve=client_curve(str(public), env={"HDEEM_WATCH_CONFIG": "/x"}))
        feeds.append(keyed)
        keyed.start()
        wait_for(keyed, lambda s: s.health.state == "live")
    finally:
        for feed in feeds:
            feed.stop()
        daemon.request_stop()
        loop.join()
        daemon.close()
