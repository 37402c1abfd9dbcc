"""``run.start`` says where the run ran (issue 15): the runner hands its hooks the CPUs it pinned to and the
arrays' size; the announcer sends them in the metadata (which every daemon version stores and accepts)."""

from __future__ import annotations

from typing import Any

from hdeem_watch.bench.announce import Announcer
from hdeem_watch.bench.runner import PlacedRunSpec, run_one
from hdeem_watch.bench.schedule import RunSpec
from hdeem_watch.daemon.book.runs import parse_run_args


class RecordingClient:
    def __init__(self) -> None:
        self.calls: list[tuple[str, Any]] = []

    def call(self, op: str, args: Any = None) -> Any:
        self.calls.append((op, args))
        return {"run_id": "r1"}


def test_a_placed_run_is_announced_with_its_cpus_and_array_bytes() -> None:
    """cpus and array_bytes ride in metadata; the SLURM metadata stays; a plain spec announces no placement."""
    announcer = Announcer("ipc:///x", client=RecordingClient(), metadata={"slurm_job_id": "7"})
    args = announcer.start_args(PlacedRunSpec("triad", 2, 1024, 3, cpus=(28, 29), array_bytes=3 * 8 * 1024))
    assert args["metadata"]["cpus"] == [28, 29] and args["metadata"]["array_bytes"] == 3 * 8 * 1024
    assert args["metadata"]["slurm_job_id"] == "7" and args["threads"] == 2
    plain = announcer.start_args(RunSpec("triad", 2, 1024, 3))
    assert "cpus" not in plain["metadata"] and "array_bytes" not in plain["metadata"]
    # an older daemon's argument check accepts it unchanged (the placement is metadata, not a new argument)
    assert parse_run_args(args).metadata["cpus"] == [28, 29]


def test_the_runner_hands_its_hooks_the_cpus_it_pinned_to() -> None:
    """on_start and on_stop see a RunSpec that also carries the pinned CPUs, the same the result reports."""
    seen: list[RunSpec] = []
    result = run_one(RunSpec("read", 1, 8 * 1024, 1), on_start=lambda s: seen.append(s) or {},
                     on_stop=lambda s: seen.append(s) or {})
    assert len(seen) == 2 and all(isinstance(s, PlacedRunSpec) for s in seen)
    placed = seen[0]
    assert isinstance(placed, PlacedRunSpec)
    assert placed.cpus == result.cpus and placed.array_bytes == 1 * 8 * 1024 * 8  # one array of 8192 doubles
    assert (placed.kernel, placed.threads, placed.elements, placed.repeat) == ("read", 1, 8 * 1024, 1)
