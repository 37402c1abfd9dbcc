"""Per-pair calibration and aging on the simulated node that is not the model (issue #16 targets).

The node is the demo's: :class:`hdeem_watch.demo.sim_runs.SimRuns` drives the real
:class:`~hdeem_watch.sources.sim.SimSource` (its own truth generator: other page placement and bank
hash, power-down, hot refresh, I/O energy per burst, ±10 % parts per pair, sensor gain/offset, noise,
0.125 W steps, aging) on a fake clock through the demo's schedule, measures each run's window as the
daemon does and feeds the daemon's own run modeller (node fit, per-pair fits, guard rail, detectors).
Sim time is what counts (``--speed 60`` turns a sim hour into a wall minute); runs follow each other
every ``--gap`` sim seconds (default: the demo's pace at ``--speed 60``, one run per ~7 sim-s), and
their windows end 0.1–0.6 sim-s (one in ten 1–3 s) after the traffic, as the demo's do at that speed
(``--exact-windows``: not).

1. Accuracy, per seed after ``--runs`` runs (default 40 ≈ 5 sim-min; at least 20 fitted per pair):
   - node-level leave-one-out error of the pairs' sum fit (target ≤ 5 %);
   - coverage: each pair's identifiable currents inside their 95 % intervals, judged against the
     *effective* truth (the currents the model converges to on this node: a fit of 256 runs of the
     same seed without noise, quantisation and temperature swing) — per current and all at once.
2. Drift: ``DDR_CD=+30%/h`` from sim time 0 (the done-when of the demo); delay to the first DDR_CD
   alarm (target ≤ 10 sim-min) and alarms naming another pair, watched for 30 sim-min.
3. False alarms: 2 sim-hours without aging; seeds with any alarm on any pair (target ≤ 5 %),
   per detector.

Usage: ``python3 benchmarks/bench_calibration.py [--seeds 20] [--quick] [--only accuracy|drift|false]
[--runs 40] [--gap 5.5] [--exact-windows]`` (20 seeds: accuracy ≈ 3 min, drift ≈ 1 min, false alarms
≈ 8.5 min on one core of the shared machine).
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

import numpy as np

from hdeem_watch.calibrate import FitOptions, fit
from hdeem_watch.calibrate.drift import ResidualCusum, arl0_two_sided
from hdeem_watch.calibrate.groups import NODE
from hdeem_watch.calibrate.observation import Observation
from hdeem_watch.demo.sim_runs import DEMO_GAP_S, DEMO_TAIL_S, SimRuns

PAIRS = ("DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH")
AGING = "DDR_CD"


def _rows(runs: SimRuns, count: int) -> dict[str, list[Observation]]:
    rows: dict[str, list[Observation]] = {p: [] for p in PAIRS}
    while min(len(v) for v in rows.values()) < count:
        done = runs.step()
        for pair, row in ((done.model or {}).get("group_observations") or {}).items():
            if done.error is None:
                rows[pair].append(Observation.from_dict(row))
    return rows


TAIL: Any = DEMO_TAIL_S


def effective_truth(seed: int, gap_s: float) -> dict[str, dict[str, float]]:
    """Per pair, what the model's currents converge to on this node (noise-free, 256 runs)."""
    quiet = SimRuns(seed, gap_s=gap_s, sim_options={"noise": False, "quantum_w": 0.0, "temp_amp_c": 0.0},
                    tail_s=TAIL)
    spec = quiet.modeller.spec
    return {pair: fit(rows, spec, FitOptions(loo="none")).calibrated for pair, rows in _rows(quiet, 256).items()}


def accuracy(seed: int, runs_count: int, gap_s: float) -> dict[str, Any]:
    """One seed: node LOO and per-pair coverage after ``runs_count`` runs."""
    runs = SimRuns(seed, gap_s=gap_s, tail_s=TAIL)
    for _ in range(runs_count):
        runs.step()
    calib = runs.modeller.group_fits.calibrators
    node = calib.calibrators[NODE].latest
    eff = effective_truth(seed, gap_s)
    inside: dict[str, list[bool]] = {}
    joint = []
    for pair in PAIRS:
        result = fit(calib.calibrators[pair].observations, runs.modeller.spec, FitOptions(loo="exact"))
        every = True
        for j, current in enumerate(result.currents):
            if not result.identifiable[j]:
                continue
            lo, hi = result.ci95_a[j]
            ok = bool(lo <= eff[pair][current] <= hi)
            inside.setdefault(current, []).append(ok)
            every &= ok
        joint.append(every)
    return {"loo_node": node.error_loo, "inside": inside, "joint": joint,
            "loo_pairs": [calib.calibrators[p].latest.error_loo for p in PAIRS]}


def watch(seed: int, aging: dict[str, float], until_s: float, gap_s: float) -> list[tuple[float, Any]]:
    """(sim s, alarm) of every alarm of one seed until ``until_s`` (stops at the aging pair's first)."""
    runs = SimRuns(1000 + seed, age=aging, gap_s=gap_s, tail_s=TAIL)
    out = []
    for done in runs.until(until_s):
        out += [(done.t_s, a) for a in done.alarms]
        if aging and any(a.group in aging for _t, a in out):
            break
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--quick", action="store_true", help="3 seeds")
    parser.add_argument("--runs", type=int, default=40, help="runs before the accuracy figures (default 40)")
    parser.add_argument("--gap", type=float, default=DEMO_GAP_S, help=f"sim s between runs (default {DEMO_GAP_S})")
    parser.add_argument("--only", choices=("accuracy", "drift", "false"), default=None)
    parser.add_argument("--exact-windows", action="store_true", help="windows end with the traffic")
    args = parser.parse_args()
    global TAIL
    TAIL = None if args.exact_windows else DEMO_TAIL_S
    seeds = 3 if args.quick else args.seeds

    if args.only in (None, "accuracy"):
        t0 = time.perf_counter()
        results = [accuracy(s, args.runs, args.gap) for s in range(seeds)]
        loo = [r["loo_node"] for r in results]
        loo_pairs = [x for r in results for x in r["loo_pairs"]]
        per_current: dict[str, list[bool]] = {}
        for r in results:
            for current, oks in r["inside"].items():
                per_current.setdefault(current, []).extend(oks)
        joint = [ok for r in results for ok in r["joint"]]
        print(f"accuracy, {seeds} seeds, {args.runs} runs each ({time.perf_counter() - t0:.0f} s):")
        print(f"  node LOO median {statistics.median(loo):.2%}, max {max(loo):.2%} (target <= 5 %); "
              f"pair LOO median {statistics.median(loo_pairs):.2%}, max {max(loo_pairs):.2%}")
        print("  inside the 95 % interval, per identifiable current (seed x pair): "
              + ", ".join(f"{c} {np.mean(v):.0%} of {len(v)}" for c, v in per_current.items()) + " (target >= 90 %)")
        print(f"  (seed, pair) with every identifiable current inside: {np.mean(joint):.0%} of {len(joint)}")

    if args.only in (None, "drift"):
        t0 = time.perf_counter()
        delays, wrong, missed = [], 0, 0
        for seed in range(seeds):
            alarms = watch(seed, {AGING: 0.30}, 1800.0, args.gap)
            hits = [t for t, a in alarms if a.group == AGING]
            wrong += any(a.group != AGING for _t, a in alarms)
            if hits:
                delays.append(min(hits))
            else:
                missed += 1
        print(f"drift {AGING} +30 %/h from sim time 0, {seeds} seeds ({time.perf_counter() - t0:.0f} s):")
        if delays:
            print(f"  detection delay median {statistics.median(delays) / 60:.1f} sim-min, max "
                  f"{max(delays) / 60:.1f} (target <= 10); missed in 30 sim-min {missed}; seeds with an alarm "
                  f"on another pair first {wrong}")
        else:
            print(f"  never detected in 30 sim-minutes ({missed} seeds)")

    if args.only in (None, "false"):
        t0 = time.perf_counter()
        by_kind: dict[str, int] = {}
        any_alarm = 0
        for seed in range(seeds):
            alarms = watch(seed, {}, 7200.0, args.gap)
            any_alarm += bool(alarms)
            for kind in {a.kind for _t, a in alarms}:
                by_kind[kind] = by_kind.get(kind, 0) + 1
            for t, a in alarms:
                print(f"    seed {seed}: {t / 60:.1f} sim-min {a.group} {a.current} {a.kind} {a.direction} "
                      f"{a.statistic:.3g}")
        runs_total = round(7200.0 / (args.gap + 1.6))
        det = ResidualCusum("defaults")
        print(f"no aging, 2 sim-hours (~{runs_total} runs), {seeds} seeds ({time.perf_counter() - t0:.0f} s): "
              f"seeds with any alarm {any_alarm}/{seeds} = {any_alarm / seeds:.0%} (target <= 5 %); by detector "
              + (", ".join(f"{k} {v}/{seeds}" for k, v in sorted(by_kind.items())) or "none")
              + f"; residual CUSUM k={det.k:g} h={det.h:g}: Gaussian ARL0 {arl0_two_sided(det.k, det.h):.3g} runs per pair")


if __name__ == "__main__":
    main()
