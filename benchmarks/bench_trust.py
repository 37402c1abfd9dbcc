"""Calibrated currents against the simulated node's truth, with and without counters (issue #32 targets).

The node is the demo's (:class:`hdeem_watch.demo.sim_runs.SimRuns`: the real sim on a fake clock,
the demo's schedule and window tails at ``--speed 60``, the daemon's own run modeller), with the
demo's hold-out runs (GUPS-like random reads, pointer chase, 2-/4-line strides, 3:1 mix: predicted
with the fit from before them, never fitted). Per seed and command source (``counters``: every row
from the sim's memory-controller counters; ``model``: from the kernel model), after ``--runs`` runs
(the daemon's calibrator keeps the newest 256):

- per current: the error of the calibrated value against the sim's truth incl. I/O (for counted rows
  ``counted_currents_a``, else ``effective_currents_a``; the sim's own analytic mapping of its hidden
  currents, never a fit), whether the fit calls it determined, whether its 95 % interval covers it;
- hold-out: median and worst relative error of the calibrated prediction (and of the datasheet's);
- runs needed: the first checkpoint (20, 40, 80, 160, 256 fitted runs) at which idd0/idd4r/idd4w are
  determined and every determined current lies within 10 % (counters) / 15 % (model).

During the runs the fit holds currents without a state of their own but skips the slower interval
parts (jackknife, mapping families); every checkpoint and the end refit with all of them, as the
daemon does after each run.

Usage: ``python3 benchmarks/bench_trust.py [--seeds 20] [--runs 300] [--only counters|model] [--node ddr5]``
(one core: ≈ 25 s per seed and source).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from typing import Any

import numpy as np

from hdeem_watch.calibrate.trust import TrustOptions
from hdeem_watch.demo.nodes import DEMO_NODES
from hdeem_watch.demo.sim_runs import DEMO_TAIL_S, SimRuns

CURRENTS = ("idd0", "idd2n", "idd3n", "idd4r", "idd4w", "idd2p", "idd3p")
KEY = ("idd0", "idd4r", "idd4w")
CHECKPOINTS = (20, 40, 80, 160, 256)
LIMIT = {"counters": 0.10, "model": 0.15}


def judge(fit: dict[str, Any], truth: dict[str, float], limit: float) -> dict[str, Any]:
    """Per current: error vs truth, determined, covered; and whether the fit meets the targets."""
    out: dict[str, Any] = {}
    for name, entry in fit["currents"].items():
        value, (lo, hi), true = entry["calibrated"], entry["ci95"], truth[name]
        out[name] = {"error": value / true - 1.0, "determined": bool(entry["identifiable"]),
                     "covered": lo is not None and hi is not None and lo <= true <= hi}
    shown = [c for c in out.values() if c["determined"]]
    key_ok = all(out.get(k, {}).get("determined") for k in KEY)
    return {"currents": out, "ok": all(abs(c["error"]) <= limit for c in shown),
            "key_determined": key_ok}


def one(seed: int, source: str, runs: int, node: str = "haswell") -> dict[str, Any]:
    """One seed, one command source, on the demo node ``node``."""
    counted = source == "counters"
    sim = SimRuns(seed, counters=counted, holdout=True, groups=False, tail_s=DEMO_TAIL_S, node=DEMO_NODES[node])
    calibrator = sim.modeller.calibrator
    cheap, full = TrustOptions(jackknife=False, draws=0), TrustOptions()
    calibrator.trust = cheap
    truth_key = "counted_currents_a" if counted else "effective_currents_a"
    holdout: list[tuple[float, float]] = []
    needed = None
    fitted = 0
    while fitted < runs:
        done = sim.step()
        model = done.model or {}
        if (done.record.get("metadata") or {}).get("holdout"):
            measured, predicted = done.record["dram_energy_j"], model.get("calibrated_j")
            if predicted is not None:
                holdout.append((predicted / measured - 1.0, model["datasheet_j"] / measured - 1.0))
            continue
        if done.error is None:
            fitted += 1
        if needed is None and fitted in CHECKPOINTS:
            calibrator.trust = full
            verdict = judge(calibrator.refit().to_dict(), sim.sim.truth()[truth_key], LIMIT[source])
            calibrator.trust = cheap
            if verdict["ok"] and (verdict["key_determined"] or not counted):
                needed = fitted
    calibrator.trust = full
    final = calibrator.refit().to_dict()
    verdict = judge(final, sim.sim.truth()[truth_key], LIMIT[source])
    cal = [abs(c) for c, _ in holdout]
    ds = [abs(d) for _, d in holdout]
    return {"seed": seed, "source": source, "fitted": fitted, "runs_needed": needed, **verdict,
            "holdout": {"n": len(cal), "median": statistics.median(cal) if cal else None,
                        "worst": max(cal) if cal else None,
                        "datasheet_median": statistics.median(ds) if ds else None,
                        "datasheet_worst": max(ds) if ds else None},
            "loo": final["error"]["loo"]}


def summary(results: list[dict[str, Any]], source: str) -> None:
    """Medians over seeds, as in docs/performance.md."""
    mine = [r for r in results if r["source"] == source]
    if not mine:
        return
    print(f"\n== {source}: {len(mine)} seeds, {mine[0]['fitted']} fitted runs each")
    for name in CURRENTS:
        rows = [r["currents"][name] for r in mine if name in r["currents"]]
        if not rows:
            continue
        errors = [abs(c["error"]) for c in rows]
        shown = [abs(c["error"]) for c in rows if c["determined"]]
        print(f"{name:6s} |error| median {100 * statistics.median(errors):5.1f} %  max {100 * max(errors):5.1f} %  "
              f"determined {sum(c['determined'] for c in rows):2d}/{len(rows)}"
              f" (worst shown {100 * max(shown) if shown else float('nan'):5.1f} %)  "
              f"covered {100 * np.mean([c['covered'] for c in rows]):5.1f} %")
    ok = sum(r["ok"] for r in mine)
    print(f"seeds where every determined current is within {100 * LIMIT[source]:.0f} %: {ok}/{len(mine)}; "
          f"idd0/idd4r/idd4w all determined: {sum(r['key_determined'] for r in mine)}/{len(mine)}")
    hold = [r["holdout"] for r in mine if r["holdout"]["n"]]
    if hold:
        print(f"hold-out ({hold[0]['n']} runs per seed): median error median {100 * statistics.median(h['median'] for h in hold):.1f} %"
              f" (seeds {100 * min(h['median'] for h in hold):.1f}–{100 * max(h['median'] for h in hold):.1f} %),"
              f" worst median {100 * statistics.median(h['worst'] for h in hold):.1f} % (max {100 * max(h['worst'] for h in hold):.1f} %);"
              f" datasheet median {100 * statistics.median(h['datasheet_median'] for h in hold):.1f} %,"
              f" worst {100 * statistics.median(h['datasheet_worst'] for h in hold):.1f} %")
    needed = [r["runs_needed"] for r in mine]
    print(f"fitted runs needed: {[n if n is not None else '>' for n in needed]}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=1)
    parser.add_argument("--runs", type=int, default=300, help="fitted runs per seed (the calibrator keeps 256)")
    parser.add_argument("--only", choices=("counters", "model"))
    parser.add_argument("--node", choices=tuple(DEMO_NODES), default="haswell",
                        help="the demo node (default: haswell; ddr5: the Sapphire Rapids-like DDR5 node)")
    parser.add_argument("--json", metavar="FILE", help="write every seed's result")
    args = parser.parse_args(argv)
    sources = [args.only] if args.only else ["counters", "model"]
    results = []
    start = time.monotonic()
    for source in sources:
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            result = one(seed, source, args.runs, args.node)
            results.append(result)
            cur = " ".join(f"{n}:{100 * c['error']:+.0f}{'' if c['determined'] else '?'}{'' if c['covered'] else '!'}"
                           for n, c in result["currents"].items())
            print(f"{source:8s} seed {seed:2d}  {cur}  hold-out med {100 * (result['holdout']['median'] or 0):.1f} % "
                  f"worst {100 * (result['holdout']['worst'] or 0):.1f} %  [{time.monotonic() - start:.0f} s]",
                  flush=True)
    for source in sources:
        summary(results, source)
    if args.json:
        with open(args.json, "w") as out:
            json.dump(results, out, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
