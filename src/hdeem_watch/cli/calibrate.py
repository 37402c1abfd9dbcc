"""``hdeem-watch calibrate``: fit DRAM currents to measured run energies (DESIGN.md §4, §7).

``hdeem-watch calibrate --runs RUNS.json [--memspec M.json] [--currents idd0,idd2n,...] [--json]
[--write-memspec OUT.json]`` reads the runs (see :mod:`hdeem_watch.calibrate.runs_file`), fits the
chosen currents and an intercept by bounded least squares, and prints a table (or, with
``--json``, one JSON object: ``currents.<name>.{datasheet, calibrated, ci95, identifiable}``,
``intercept_j``, ``error.{before, after, loo}``, ``observability.{condition_number,
singular_values}``, ...). ``--write-memspec`` writes the memspec with the calibrated currents.

The fit keeps the currents within physically consistent limits where a box bound can say so
(:mod:`hdeem_watch.calibrate.physical`; ``--no-physical-bounds`` turns that off);
``--physical-rules`` keeps the rules between two calibrated currents too (IDD3N ≥ IDD2N, IDD0
above the tRAS/tRC mix, ...), for a memspec DRAMPower can use. A fit that still breaks an
ordering rule between two calibrated currents (e.g. IDD3N < IDD2N) is reported: a
warning naming the rules, ``"physical": false`` and ``"violations"`` in the JSON, and a memspec
written with it carries ``"calibration": {"physical": false, "violations": [...]}`` beside its
``memspec`` object — loading it needs ``--allow-unphysical`` (here, for ``--memspec`` or the
memspec RUNS.json names) or ``allow_unphysical=True``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

from hdeem_watch.calibrate.fit import FitOptions, check_bound_a, fit
from hdeem_watch.calibrate.observation import DEFAULT_CURRENTS
from hdeem_watch.calibrate.physical import fit_violations
from hdeem_watch.calibrate.result import FitResult, energy_units_warning
from hdeem_watch.calibrate.runs_file import read_calibration_settings, read_runs_file
from hdeem_watch.calibrate.trust import TrustOptions, trusted_fit
from hdeem_watch.dram.memspec import MemSpec
from hdeem_watch.errors import InputError


def register(subparsers: Any) -> None:
    """Add the ``calibrate`` subcommand."""
    parser = subparsers.add_parser(
        "calibrate", help="fit DRAM currents to measured run energies (bounded least squares)",
        description="Fit memspec currents (and an intercept >= 0) to the measured energies of runs "
                    "given as DRAMPower command traces or command statistics.")
    parser.add_argument("--runs", required=True, metavar="RUNS.json",
                        help='{"memspec": path, "runs": [{"name", "measured_j", "trace"|"stats", "scale"}]}')
    parser.add_argument("--memspec", metavar="M.json",
                        help="memspec overriding the one RUNS.json names (a path or preset:NAME)")
    parser.add_argument("--currents", default=None, metavar="LIST",
                        help=f"comma-separated currents to calibrate (default: the file's calibration.currents, "
                        f"else {','.join(DEFAULT_CURRENTS)})")
    parser.add_argument("--bounds", default="", metavar="NAME=LO:HI,...",
                        help="bounds in A overriding 0..datasheet, e.g. idd4r=0:0.2")
    parser.add_argument("--no-intercept", action="store_true", help="do not fit a per-run energy offset")
    parser.add_argument("--no-physical-bounds", action="store_true",
                        help="bound currents by 0..datasheet only (default: also by the physically "
                             "consistent limits against the currents not calibrated, e.g. IDD3N >= IDD3P)")
    parser.add_argument("--physical-rules", action="store_true",
                        help="keep the order between calibrated currents too (IDD3N >= IDD2N, IDD4R >= "
                             "IDD3N, IDD0 above the tRAS/tRC mix, ...): a physical memspec, at some "
                             "accuracy (default: effective currents, warned when unphysical)")
    parser.add_argument("--allow-unphysical", action="store_true",
                        help="load a memspec whose currents break the physical ordering (e.g. one "
                             "written from an unphysical fit)")
    parser.add_argument("--prior-weight", type=float, default=0.0, metavar="W",
                        help="weight of a prior toward the datasheet values (0 = off)")
    parser.add_argument("--trust", choices=("auto", "on", "off"), default="auto",
                        help="hold currents without a state of their own and widen the intervals by what the rows "
                        "do not know, as the daemon does (docs/calibration.md); auto: when the file says the "
                        "daemon did (calib export)")
    parser.add_argument("--uncertainty", choices=("analytic", "bootstrap"), default="analytic",
                        help="95%% intervals from the active-set covariance or a residual bootstrap")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--write-memspec", metavar="OUT.json", help="write the calibrated memspec here")
    parser.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    settings = read_calibration_settings(args.runs)
    listed = settings.get("currents") if isinstance(settings.get("currents"), list) else None
    text = args.currents if args.currents is not None else ",".join(map(str, listed or DEFAULT_CURRENTS))
    currents = [c.strip() for c in text.split(",") if c.strip()]
    if not currents:
        raise InputError("--currents: expected a comma-separated list of current names")
    if not math.isfinite(args.prior_weight) or args.prior_weight < 0:
        raise InputError(f"--prior-weight: {args.prior_weight!r}; expected a number >= 0")
    bounds = parse_bounds(args.bounds)
    spec, observations = read_runs_file(args.runs, args.memspec, allow_unphysical=args.allow_unphysical)
    options = FitOptions(currents=currents, bounds=bounds, intercept=not args.no_intercept,
                         prior_weight=args.prior_weight, uncertainty=args.uncertainty,
                         physical=not args.no_physical_bounds, rules=args.physical_rules)
    trust = args.trust == "on" or (args.trust == "auto" and settings.get("trust") is True)
    result = trusted_fit(observations, spec, options, trust=TrustOptions()) if trust else fit(observations, spec, options)
    violations = fit_violations(spec, result.calibrated)
    warnings = [w for w in (energy_units_warning(result.runs),) if w]
    if violations:
        warnings.append(f"the calibrated currents are unphysical ({'; '.join(violations)}): the runs do not "
                        "separate these currents, or the model misses an effect; a memspec written from "
                        "this fit is marked and loads only with --allow-unphysical")
    for warning in warnings:
        print(f"hdeem-watch calibrate: warning: {warning}", file=sys.stderr)
    written = None
    if args.write_memspec:
        write_calibrated_memspec(spec, result, violations, args.write_memspec)
        written = str(args.write_memspec)
    if args.json:
        out = result.to_dict()
        out["memspec"] = spec.memory_id
        out["written_memspec"] = written
        out["physical"] = not violations
        out["violations"] = violations
        out["warnings"] = warnings
        print(json.dumps(out, allow_nan=False))
    else:
        print(format_table(result, spec.memory_id))
        if written:
            print(f"calibrated memspec written to {written}")
    return 0


def write_calibrated_memspec(spec: MemSpec, result: FitResult, violations: list[str], path: str) -> None:
    """Write ``spec`` with the calibrated currents to ``path``, marked with ``"calibration":
    {"physical", "violations", "status", "n_runs"}`` beside its ``memspec`` object (DRAMPower
    reads only ``memspec``).

    Raises:
        InputError: the file cannot be written.
    """
    tree = spec.with_currents(result.calibrated).to_json_dict()
    tree["calibration"] = {"physical": not violations, "violations": violations, "status": result.status,
                           "n_runs": result.n_runs}
    try:
        Path(path).write_text(json.dumps(tree, indent=2) + "\n", encoding="utf-8")
    except OSError as error:
        raise InputError(f"--write-memspec {path}: cannot write: {error.strerror or error}") from None


def parse_bounds(text: str) -> dict[str, tuple[float, float]] | None:
    """``"idd4r=0:0.2,idd0=0.01:0.1"`` → ``{"idd4r": (0.0, 0.2), ...}`` (None if empty).

    Raises:
        InputError: a malformed item.
    """
    out: dict[str, tuple[float, float]] = {}
    for item in (part.strip() for part in text.split(",")):
        if not item:
            continue
        name, _, rest = item.partition("=")
        lo, _, hi = rest.partition(":")
        try:
            bound = (float(lo), float(hi))
        except ValueError:
            raise InputError(f"--bounds: {item!r}; expected NAME=LOWER:UPPER in amperes") from None
        check_bound_a(f"--bounds {name.strip()}", *bound)
        out[name.strip().lower()] = bound
    return out or None


def _ma(value: float) -> str:
    return "—" if not math.isfinite(value) else f"{value * 1e3:.2f}"


def _pct(value: float) -> str:
    return "—" if not math.isfinite(value) else f"{value * 100:.2f} %"


def format_table(result: FitResult, memory_id: str) -> str:
    """The human-readable report of a fit."""
    lines = [f"calibrated {len(result.currents)} currents of {memory_id} on {result.n_runs} runs "
             f"(status {result.status}, intervals: {result.uncertainty})",
             f"{'current':<8} {'datasheet mA':>12} {'calibrated mA':>13} {'ratio':>6}  {'95 % interval mA':<20} "
             f"{'sensitivity':>11}  determined"]
    for j, name in enumerate(result.currents):
        ds, cal = result.datasheet_a[j], result.calibrated_a[j]
        lo, hi = result.ci95_a[j]
        ratio = f"{cal / ds:.3f}" if ds > 0 else "—"
        bound = f" (at {result.at_bound[j]} bound)" if result.at_bound[j] else ""
        lines.append(f"{name:<8} {_ma(ds):>12} {_ma(cal):>13} {ratio:>6}  {'[' + _ma(lo) + ', ' + _ma(hi) + ']':<20} "
                     f"{result.sensitivity[j]:>11.3f}  {'yes' if result.identifiable[j] else 'NO (weak)'}{bound}")
    if result.rules_held:
        lines.append(f"held at a physical rule (the data wants past it): {', '.join(result.rules_held)}")
    if result.trust is not None:
        from hdeem_watch.cli.calib import trust_lines
        from hdeem_watch.fit_record import FitRecord

        lines.extend(line.strip() for line in trust_lines(FitRecord.from_dict(result.to_dict())))
    if result.intercept_fitted:
        lo, hi = result.intercept_ci95_j
        lines.append(f"intercept {result.intercept_j:.4g} J per run  [{lo:.4g}, {hi:.4g}]")
    lines.append(f"mean |relative error|: datasheet {_pct(result.error_before)}, calibrated "
                 f"{_pct(result.error_after)}, leave-one-out {_pct(result.error_loo)}")
    sv = ", ".join(f"{s:.3g}" for s in result.singular_values)
    cond = "inf" if not math.isfinite(result.condition_number) else f"{result.condition_number:.3g}"
    lines.append(f"observability: condition number {cond}, rank {result.rank}, singular values {sv}")
    weak = [n for n, ok in zip(result.currents, result.identifiable) if not ok]
    if weak:
        lines.append(f"not determined by these runs: {', '.join(weak)} (see their intervals; add runs that "
                     "exercise them, or calibrate fewer currents)")
    return "\n".join(lines)
