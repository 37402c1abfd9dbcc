"""Runs modelled from memory-controller counters (issue 17): opaque jobs, kernel runs with a cross-check.

The daemon's real core (run book, operations, store and model workers) over the simulated node with
its own IMC counters (``counters = "sim"``), on a fake clock (``benchmarks/counter_rig.py``).
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from counter_rig import CounterSimNode
from hdeem_watch.counters.source import CounterSnapshot
from hdeem_watch.daemon.book.runs import OPAQUE_KERNEL, parse_run_args
from hdeem_watch.daemon.counters.windows import CounterWindows
from hdeem_watch.sim.jobs import JOB_KERNEL

# One worker runs the module, so its module-scoped fixture is built once, not once per worker.
pytestmark = pytest.mark.xdist_group("daemon-counter_runs")

CURRENTS = ("idd0", "idd2n", "idd3n", "idd4r", "idd4w", "idd2p", "idd3p")


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory: pytest.TempPathFactory):
    """A node calibrated on a few kernel runs (with counters), then three opaque jobs."""
    node = CounterSimNode(tmp_path_factory.mktemp("counters"), currents=CURRENTS)
    node.advance(1.0)
    kernels = [node.run(*spec) for spec in [("idle", 1, 0, 1), ("read", 12, 1 << 23, 240),
                                            ("triad", 4, 1 << 23, 160), ("copy", 8, 1 << 23, 200),
                                            ("idle", 1, 0, 1), ("add", 24, 1 << 23, 240),
                                            ("read", 2, 1 << 22, 160), ("triad", 12, 1 << 23, 240)]]
    jobs = [node.run(None, threads, seconds=seconds) for threads, seconds in ((12, 6.0), (24, 8.0), (4, 5.0))]
    published = list(node.published)
    node.close()
    return kernels, jobs, published


def test_a_run_without_a_kernel_is_an_opaque_job() -> None:
    """``run.start`` without a kernel (or with null) is the opaque job the sim plays a hidden mix for."""
    assert parse_run_args({"threads": 4}).kernel == OPAQUE_KERNEL == JOB_KERNEL
    assert parse_run_args({"kernel": None}).kernel == OPAQUE_KERNEL


def test_opaque_jobs_are_modelled_from_counters_alone(calibrated) -> None:
    """An opaque job's run.stop result has a model from counters (``model.source == "counters"``) whose
    calibrated prediction is near the measured energy (eight kernel runs for seven currents: the accuracy
    target, ≤ 5 % over ≥ 20 jobs after a full calibration, is benchmarks/bench_counters.py's)."""
    _kernels, jobs, _published = calibrated
    for job in jobs:
        model = job["model"]
        assert job["model_error"] is None, job["model_error"]
        assert model["source"] == "counters" and "kernel_model" not in model
        assert job["counters"]["source"] == "sim" and job["counters"]["status"] == "ok"
        assert job["counters"]["window_s"] == pytest.approx(job["window_s"], rel=0.02)
        assert model["counts"]["act"] > 0 and model["counts"]["rd"] > 0
        assert abs(model["predicted_j"] / job["dram_energy_j"] - 1) < 0.15


def test_kernel_runs_show_the_kernel_model_beside_the_counters(calibrated) -> None:
    """A kernel run with counters: the model comes from the counters, the kernel model's counts beside them;
    reads and writes agree (the same lines), activations need not (the sim's row hits are its own)."""
    kernels, _jobs, _published = calibrated
    for run in kernels:
        model = run["model"]
        assert model["source"] == "counters"
        check = model["kernel_model"]
        assert set(check) >= {"kernel_counts", "counter_counts", "ratio", "datasheet_j", "predicted_j"}
        if run["kernel"] != "idle":
            assert check["ratio"]["rd"] == pytest.approx(1.0, rel=0.01)
            if check["kernel_counts"]["wr"]:
                assert check["ratio"]["wr"] == pytest.approx(1.0, rel=0.01)


def test_the_counters_topic_carries_command_rates(calibrated) -> None:
    """Not published by the harness (the service's heartbeat does); the window rates are per channel."""
    _kernels, jobs, _published = calibrated
    assert set(jobs[0]["counters"]["channels"]) == {f"S{s}.imc{b}" for s in (0, 1) for b in (0, 1, 4, 5)}


def test_without_counters_an_opaque_job_says_why_it_has_no_model(tmp_path: Path) -> None:
    node = CounterSimNode(tmp_path, counters=False)
    try:
        node.advance(0.5)
        job = node.run(None, 4, seconds=1.5)
    finally:
        node.close()
    assert job["model"] is None and "counters only" in job["model_error"]


def window(run_id: str, start: int, target: int | None = None):
    run = type("R", (), {"run_id": run_id, "samples_ns": None})()
    return type("W", (), {"run": run, "t_start_mono_ns": start, "target_t_ns": target})()


def test_counter_windows_read_at_edges_and_interpolate_the_ends() -> None:
    """A new run window asks for a read; its start is interpolated between reads; a closing window asks
    until a read reaches its end; the run's counts are the interpolated difference."""
    cw = CounterWindows("sim", table_key="haswell-ep", ranks=2, refresh_complete=False, sensors={},
                        heartbeat_ns=10**12)

    def snap(t: int) -> CounterSnapshot:
        return CounterSnapshot(t, {"S0.imc0": {"act": float(t), "cas_rd": 2.0 * t}})

    cw.observe(snap(0), now_mono_ns=0)
    w = window("r1", 250)
    assert not cw.due(1, []) and cw.due(1, [w])
    cw.observe(snap(1000), now_mono_ns=1)
    cw.track([w], sample_time=lambda t: t)
    assert not cw.due(2, [w])
    w.target_t_ns = 3000
    assert cw.due(2, [w])
    cw.observe(snap(4000), now_mono_ns=3)
    assert not cw.due(4, [w])
    w.run.samples_ns = {"DDR_AB": [200, 3000]}
    result = cw.finish(w.run, ["DDR_AB"])
    assert result is not None and result["status"] == "ok"
    assert result["channels"]["S0.imc0"] == {"act": 2750.0, "cas_rd": 5500.0}
    assert result["window_s"] == pytest.approx(2750e-9)


def test_a_window_past_the_newest_read_is_short_not_invented() -> None:
    cw = CounterWindows("sim", table_key="haswell-ep", ranks=2, refresh_complete=False, sensors={})
    cw.observe(CounterSnapshot(0, {"c": {"act": 0.0}}), now_mono_ns=0)
    w = window("r1", 0)
    cw.track([w], sample_time=lambda t: t)
    cw.observe(CounterSnapshot(100, {"c": {"act": 10.0}}), now_mono_ns=1)
    w.run.samples_ns = {"DDR_AB": [0, 300]}
    result = cw.finish(w.run, ["DDR_AB"])
    assert result is not None and result["status"].startswith("short") and result["channels"]["c"]["act"] == 10.0
    assert cw.finish(w.run, ["DDR_AB"]) is None  # the start was used up


def test_a_source_that_counts_at_any_time_counts_to_the_last_sample_not_the_last_read() -> None:
    """The sim counts at any time it knows (``read_at``): a window whose samples reach past the newest
    read is counted exactly to its last sample, not cut short at the read (which would leave the
    window's energy with fewer commands than it had)."""
    cw = CounterWindows("sim", table_key="haswell-ep", ranks=2, refresh_complete=False, sensors={})
    cw.observe(CounterSnapshot(0, {"c": {"act": 0.0}}), now_mono_ns=0)
    w = window("r1", 0)

    def exact(t: int) -> CounterSnapshot:
        return CounterSnapshot(t, {"c": {"act": t / 10}})

    cw.track([w], sample_time=lambda t: t, exact=exact)
    cw.observe(CounterSnapshot(100, {"c": {"act": 10.0}}), now_mono_ns=1)
    w.run.samples_ns = {"DDR_AB": [0, 300]}
    result = cw.finish(w.run, ["DDR_AB"], exact)
    assert result is not None and result["status"] == "ok" and result["channels"]["c"]["act"] == 30.0
    assert result["window_s"] == pytest.approx(300e-9)


def test_rates_are_per_second_with_the_power_down_share() -> None:
    cw = CounterWindows("sim", table_key="haswell-ep", ranks=2, refresh_complete=False, sensors={"c": "DDR_AB"})
    assert cw.rates() == {}
    zero = {"act": 0.0, "cas_rd": 0.0, "cas_wr": 0.0, "dclk": 0.0, "cke_on_rank0": 0.0, "cke_on_rank1": 0.0}
    cw.observe(CounterSnapshot(0, {"c": zero}), now_mono_ns=0)
    cw.observe(CounterSnapshot(2 * 10**9, {"c": {"act": 10.0, "cas_rd": 40.0, "cas_wr": math.nan, "dclk": 100.0,
                                               "cke_on_rank0": 50.0, "cke_on_rank1": 30.0}}), now_mono_ns=1)
    rates = cw.rates()["c"]
    assert (rates["act_per_s"], rates["rd_per_s"]) == (5.0, 20.0) and math.isnan(rates["wr_per_s"])
    assert rates["powerdown_share"] == pytest.approx(0.6)


def test_a_failed_read_is_kept_for_the_status_until_a_read_succeeds() -> None:
    cw = CounterWindows("perf", table_key="haswell-ep", ranks=2, refresh_complete=False, sensors={},
                        heartbeat_ns=100)
    cw.failed(OSError(19, "No such device"), now_mono_ns=0)
    assert cw.error == "OSError: [Errno 19] No such device"
    assert not cw.due(50) and cw.due(100)  # retried at the next heartbeat, not at every poll
    cw.observe(CounterSnapshot(0, {}), now_mono_ns=100)
    assert cw.error is None


def test_an_aborted_run_leaves_no_counter_start_behind() -> None:
    cw = CounterWindows("sim", table_key="haswell-ep", ranks=2, refresh_complete=False, sensors={})
    cw.observe(CounterSnapshot(0, {"c": {"act": 0.0}}), now_mono_ns=0)
    w = window("r9", 0)
    cw.track([w], sample_time=lambda t: t)
    assert cw.due(1, [window("r10", 1)]) and not cw.due(1, [w])
    cw.forget("r9")
    assert cw.finish(w.run, []) is None
