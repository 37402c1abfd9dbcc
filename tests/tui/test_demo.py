"""``hdeem-watch demo`` end to end: in a real terminal (tmux), headless, and its schedule."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
import uuid

import numpy as np
import psutil
import pytest

from hdeem_watch.demo.schedule import (
    IDLE_SECONDS,
    RUN_LENGTHS_S,
    TARGET_RUN_S,
    demo_plan,
    demo_round,
    run_seconds,
)
from hdeem_watch.run_record import RunRecord

DRAM = ("DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH")
NUMBER = re.compile(r"^-?\d+\.\d+$")


def _tmux(*args: str) -> str:
    return subprocess.run(["tmux", *args], capture_output=True, text=True, check=False).stdout


def _dram_values(screen: str) -> dict[str, str]:
    values = {}
    for line in screen.splitlines():
        parts = line.split()
        if len(parts) >= 2 and parts[0] in DRAM and NUMBER.match(parts[1]):
            values[parts[0]] = parts[1]
    return values


def _has_calibration_table(screen: str) -> bool:
    rows = [line for line in screen.splitlines() if re.search(r"\bidd\d\w*\s+\d+\.\d", line)]
    return "calibration" in screen and "datash" in screen and len(rows) >= 3


@pytest.mark.slow
@pytest.mark.tmux
@pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is installed by .ci/run")
def test_demo_in_a_real_terminal() -> None:
    """In a 100×30 tmux terminal the demo shows the four DIMM pairs with changing values and a calibration table, and q stops it cleanly."""
    session = f"hwdemo-{uuid.uuid4().hex[:8]}"
    command = f"{sys.executable} -m hdeem_watch demo --duration 90"
    env = {**os.environ, "TERM": "xterm-256color"}
    subprocess.run(["tmux", "new-session", "-d", "-s", session, "-x", "100", "-y", "30", command], check=True, env=env)
    try:
        pane_pid = int(_tmux("display-message", "-p", "-t", session, "#{pane_pid}").strip())
        deadline = time.monotonic() + 60
        screen = ""
        while time.monotonic() < deadline:
            screen = _tmux("capture-pane", "-p", "-t", session)
            if len(_dram_values(screen)) == 4 and _has_calibration_table(screen):
                break
            time.sleep(0.5)
        assert len(_dram_values(screen)) == 4, screen
        assert _has_calibration_table(screen), screen
        assert "LIVE" in screen.splitlines()[0]
        first = _dram_values(screen)
        changed = False
        for _ in range(20):
            time.sleep(0.5)
            later = _dram_values(_tmux("capture-pane", "-p", "-t", session))
            if len(later) == 4 and later != first:
                changed = True
                break
        assert changed, "the DRAM values did not change on screen"
        children = psutil.Process(pane_pid).children(recursive=True)
        assert any("daemon" in " ".join(p.cmdline()) for p in children)
        subprocess.run(["tmux", "send-keys", "-t", session, "q"], check=True)
        _, alive = psutil.wait_procs([psutil.Process(pane_pid), *children], timeout=20)
        # A zombie has exited (only its parent's reaping is missing) and a vanished pid is gone:
        # neither is still running. process_iter reads each survivor once and never raises for them.
        pids = {p.pid for p in alive}
        running = [p.info for p in psutil.process_iter(["pid", "status", "cmdline"])
                   if p.pid in pids and p.info["status"] != psutil.STATUS_ZOMBIE]
        assert not running, f"still running after q: {running}"
    finally:
        subprocess.run(["tmux", "kill-session", "-t", session], capture_output=True, check=False)


@pytest.mark.slow
def test_demo_headless_prints_progress_and_stops_the_daemon() -> None:
    """--headless prints runs, calibration and power as text lines and leaves no daemon behind (5 s
    at 4x sim speed: ~6 runs, more than 10 s at speed 1 gave)."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "hdeem_watch", "demo", "--headless", "--duration", "5", "--speed", "4"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        children = []
        deadline = time.monotonic() + 10
        while not children and time.monotonic() < deadline:
            children = [p for p in psutil.Process(proc.pid).children(recursive=True) if "daemon" in " ".join(p.cmdline())]
            time.sleep(0.2)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    lines = out.splitlines()
    assert any(line.startswith("power ") and all(ch in line for ch in DRAM) for line in lines), out
    runs = [line for line in lines if line.startswith("run ")]
    assert len(runs) >= 3, out
    assert any(line.startswith("calib ") and "error before" in line for line in lines), out
    assert children, "the demo started no daemon subprocess"
    _, alive = psutil.wait_procs(children, timeout=10)
    assert not alive


def test_demo_schedule_runs_last_about_the_target() -> None:
    """Each demo run is sized with the modelled line rate to last one of the target lengths; a round has idle + 7 kernels."""
    runs = demo_round("24")
    assert runs[0].spec.kernel == "idle" and len(runs) == 8  # round 0: no hold-out run yet
    assert all(r.spec.threads == 24 for r in runs)
    for i, run in enumerate(runs[1:]):
        target = RUN_LENGTHS_S[i % len(RUN_LENGTHS_S)]
        assert run.seconds == pytest.approx(run_seconds(run.spec))
        assert abs(run.seconds - target) < 0.2 * target
    assert len({r.spec.repeat for r in runs[1:]}) > 1  # sized per kernel, not one constant
    assert abs(sum(RUN_LENGTHS_S) / len(RUN_LENGTHS_S) - TARGET_RUN_S) < 1e-9


def test_demo_design_varies_threads_and_lengths() -> None:
    """Over the first minute the design varies thread counts (1..24), run lengths and idle lengths, so that
    standby power × window and the fit's per-run intercept are not the same column."""
    plan = demo_plan(4)
    threads = {r.spec.threads for r in plan if r.spec.kernel != "idle"}
    assert threads == {1, 4, 12, 24}
    idle = [r.seconds for r in plan if r.spec.kernel == "idle"]
    assert idle == list(IDLE_SECONDS) and len(set(idle)) == len(idle)
    kernel_lengths = [round(r.seconds, 1) for r in plan if r.spec.kernel != "idle"]
    # 1.25–1.75 s: none shorter, or the guard rail (100 samples) drops runs that come out at 0.99 s
    assert max(kernel_lengths) / min(kernel_lengths) > 1.3 and min(kernel_lengths) >= 1.2
    windows = np.array([r.seconds for r in plan])
    assert windows.std() / windows.mean() > 0.2


@pytest.mark.slow  # a long end-to-end accuracy check (30 refits on the sim's truth, ~5 s of CPU)
def test_demo_design_determines_the_currents_near_the_effective_truth() -> None:
    """The first 30 runs of the demo's design, measured on the sim's truth with 0.3 % noise, make all five currents
    identifiable and within 8 % of the sim's effective truth; the datasheet model overestimates ≥ 1.3×."""
    from hdeem_watch.calibrate.run_model import RunModeller
    from hdeem_watch.sim.model import (
        TruthModel,
        default_model,
        effective_currents,
        run_truth_energy_j,
    )

    model = default_model()
    currents = TruthModel(model.names, model.datasheet, 0).currents(0.0)
    effective = effective_currents(model, currents, 0.0).mean(axis=0)
    # the design's information on rows that are right by construction (the model's own commands): the
    # plain fit; the daemon's shown fit also says what rests on unconfirmed activations (test_trust_sim)
    modeller = RunModeller("samsung-m393a1g43db0-cpb", dimms=8, trust=False)
    rng = np.random.default_rng(1)
    fit: dict = {}
    for i, run in enumerate(demo_plan(4)[:30]):
        s = run.spec
        energy = run_truth_energy_j(model, currents, s.kernel, s.elements, s.threads, s.repeat, run.seconds)
        _m, fit, error = modeller.evaluate(RunRecord.from_dict({"run_id": f"r{i}", "state": "modelling", "kernel": s.kernel, "threads": s.threads,
                                            "elements": s.elements, "repeat": s.repeat, "window_s": run.seconds,
                                            "dram_energy_j": energy * (1 + rng.normal(0, 0.003)), "t_stop_ns": i}))
        assert error is None
    assert fit["error"]["before"] > 0.3 and fit["error"]["after"] < 0.02 and fit["error"]["loo"] < 0.03
    for name, entry in fit["currents"].items():
        truth = effective[model.names.index(name)]
        assert entry["identifiable"], name
        assert abs(entry["calibrated"] / truth - 1) < 0.08, (name, entry["calibrated"], truth)


def test_cli_bad_input_is_exit_2() -> None:
    """Bad flags of tui/demo are one-line errors with exit code 2."""
    from hdeem_watch.cli import main

    assert main(["tui", "--connect", "node7:5591"]) == 2
    assert main(["tui", "--fps", "0"]) == 2
    assert main(["demo", "--duration", "-1"]) == 2


def test_slurm_endpoints_use_the_documented_port() -> None:
    """--slurm connects to every node of the allocation at tcp://<node>:5591 (or the given port)."""
    from hdeem_watch.cli.tui import slurm_endpoints
    from hdeem_watch.errors import InputError

    env = {"SLURM_JOB_NODELIST": "taurusi[6001-6002]"}
    assert slurm_endpoints(env=env) == ["tcp://taurusi6001:5591", "tcp://taurusi6002:5591"]
    assert slurm_endpoints(7000, env=env)[0] == "tcp://taurusi6001:7000"
    with pytest.raises(InputError):
        slurm_endpoints(env={})


@pytest.mark.slow
def test_tui_without_a_terminal_prints_text_lines(fake_node) -> None:  # type: ignore[no-untyped-def]
    """hdeem-watch tui with stdout not a terminal falls back to text progress (and says so on stderr)."""
    done = subprocess.run(
        [sys.executable, "-m", "hdeem_watch", "tui", "--connect", fake_node.control_endpoint, "--duration", "2.5"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "not a terminal" in done.stderr
    lines = done.stdout.splitlines()
    assert any(line.startswith("state  fake1 live") for line in lines), done.stdout
    assert any(line.startswith("power ") and all(ch in line for ch in DRAM) for line in lines), done.stdout


def test_hold_out_runs_join_from_the_fifth_round() -> None:
    """Every thread count is fitted once before the first hold-out run; then each round ends with one,
    a kernel the fit never sees, cycling through the hold-out kernels."""
    from hdeem_watch.demo.schedule import HOLDOUT_FROM_ROUND
    from hdeem_watch.dram.kernels import HOLDOUT_KERNELS

    assert HOLDOUT_FROM_ROUND == 4 and not any(r.holdout for r in demo_plan(4))
    rounds = [demo_round(t, 4 + i) for i, t in enumerate(("24", "4", "12", "1", "24"))]
    last = [r[-1] for r in rounds]
    assert all(r.holdout for r in last) and [r.spec.kernel for r in last] == list(HOLDOUT_KERNELS)
    assert [r.spec.threads for r in last] == [24, 4, 12, 1, 24]
    assert all(1.0 < r.seconds < 2.0 for r in last)
    assert not any(r.holdout for r in demo_round("24", 5, holdout=False))
