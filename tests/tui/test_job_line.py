"""The TUI's current-job line: the SLURM jobs open on the focused node, from the status reply and
the daemon's ``job`` events; no line (no space taken) when none is open."""

from __future__ import annotations

from hdeem_watch.tui.app import HdeemWatchApp
from hdeem_watch.tui.model import NodeModel
from hdeem_watch.tui.provider import StaticProvider
from hdeem_watch.tui.snapshot import JobView, NodeSnapshot
from hdeem_watch.wire import protocol

WALL = 1_800_000_000 * 10**9


def _job_event(seq: int, event: str, job_id: str, user: str) -> protocol.Message:
    body = {"seq": seq, "node": "n1", "t_ns": 0, "event": event,
            "job": {"job_id": job_id, "user": user, "t_start_ns": WALL - 65 * 10**9,
                    "state": "running" if event == "start" else "done"}}
    return protocol.decode(protocol.encode(protocol.topic("n1", "job"), body))


def test_open_jobs_come_from_the_status_reply_and_the_job_events() -> None:
    """The status reply lists the open jobs; a start event adds one, a stop event removes it."""
    model = NodeModel("ipc:///x")
    model.apply_status({"uptime_s": 1.0, "jobs": [{"job_id": "7", "user": "alice", "t_start_ns": WALL - 10**9,
                                                            "state": "running"}]},
                       wall_ns=WALL)
    model.apply(_job_event(1, "start", "8", "bob"), recv_mono_ns=1)
    snap = model.snapshot(now_mono_ns=2, now_wall_ns=WALL, window_s=60.0, width=None)
    assert snap.jobs == (JobView("7", "alice", 1.0), JobView("8", "bob", 65.0))
    model.apply(_job_event(2, "stop", "7", "alice"), recv_mono_ns=3)
    assert [j.job_id for j in model.snapshot(now_mono_ns=4, now_wall_ns=WALL, window_s=60.0, width=None).jobs] == ["8"]


async def test_the_app_shows_the_current_job_and_no_line_without_one() -> None:
    """With a job open the line names it (id, user, elapsed); without, the line takes no space."""
    with_job = NodeSnapshot(node="n1", built_mono_ns=1, window_s=60.0, jobs=(JobView("4242", "alice", 3723.0),))
    app = HdeemWatchApp(StaticProvider([with_job]), fps=0.2, clock=lambda: 1)
    async with app.run_test(size=(80, 24)):
        app.paint()
        line = app.query_one("#job")
        assert line.display and "job 4242 (alice) 1:02:03" in str(line.render())
    bare = HdeemWatchApp(StaticProvider([NodeSnapshot(node="n1", built_mono_ns=1, window_s=60.0)]), fps=0.2,
                         clock=lambda: 1)
    async with bare.run_test(size=(80, 24)):
        bare.paint()
        assert not bare.query_one("#job").display
