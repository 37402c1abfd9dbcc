"""``hdeem-watch calib show|reset|export``: inspect, reset and export a running daemon's calibration.

``calib show [--group G] [--json]`` prints the fits ``calib.get`` returns: the daemon's node fit (with
the source of its rows' commands), and from a daemon with per-group calibration (docs/calibration.md,
"Per-sensor-group fits") the fit of the groups' sum (``total``) and one per sensor group, with their
drift alarms and the runs not fitted and why. ``calib reset [--group G]``
forgets the runs of every fit (or of one group). ``calib export --out RUNS.json [--group G]`` writes
exactly the calibration rows the daemon's fit holds as a RUNS.json that ``hdeem-watch calibrate
--runs`` reads back to the same currents (each run's model columns, constant, measured energy and
command source; the fit's currents under ``calibration``; the finished runs it did not fit, and why,
under ``not_fitted``). ``--connect EP``
names the daemon's control endpoint (default: the local daemon's).

Exit codes: 0 done, 1 the daemon is unreachable or refused, 2 bad input (an unknown group).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

from hdeem_watch.cli.daemon_client import add_connect_arguments, open_client
from hdeem_watch.cli.numbers import counted
from hdeem_watch.errors import InputError
from hdeem_watch.fit_record import FitRecord

NODE = "node"
#: The fit of the sensor groups' sum (kernel runs only), beside the node fit.
TOTAL = "total"


def register(subparsers: Any) -> None:
    """Add the ``calib`` subcommand."""
    parser = subparsers.add_parser(
        "calib", help="show, reset or export a running daemon's calibration",
        description="Inspect, reset or export the calibration of a running daemon (over its control socket).")
    actions = parser.add_subparsers(dest="action", metavar="ACTION", parser_class=type(parser))
    for name, text in (("show", "print the node fit and the per-group fits"),
                       ("reset", "forget the calibration runs (of every fit, or of --group)"),
                       ("export", "write the calibration rows as RUNS.json for 'hdeem-watch calibrate'")):
        sub = actions.add_parser(name, help=text, description=text)
        sub.add_argument("--group", metavar="G", help="one sensor group (e.g. DDR_CD, DRAM1) or 'node'")
        add_connect_arguments(sub)
        if name == "show":
            sub.add_argument("--json", action="store_true", help="print one JSON object")
        if name == "reset":
            sub.add_argument("--yes", action="store_true", help="confirm: the runs cannot be brought back")
        if name == "export":
            sub.add_argument("--out", required=True, metavar="RUNS.json", help="where to write the runs")
        sub.set_defaults(func=_run)
    parser.set_defaults(func=lambda _args: (parser.print_help(sys.stderr), 2)[1])


def _client(args: argparse.Namespace) -> Any:
    """The control client of ``--connect``/``--timeout``/``--server-key``/``--client-key`` (one
    line, exit 2, for a bad endpoint: hdeem_watch.cli.daemon_client)."""
    return open_client(args)


def fits_of(body: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Name → entry (``fit``, ``runs``, ``alarms``, ...) of a ``calib.get`` body: ``node`` first (the
    daemon's node fit: every fitted run, from the commands its source gave), then ``total`` (with
    sensor groups: the fit of the groups' sum, kernel runs only) and the groups."""
    node: dict[str, Any] = {"fit": body.get("fit"), "runs": body.get("runs"), "drift": body.get("drift"), "alarms": []}
    total = {TOTAL: dict(body["total"])} if isinstance(body.get("total"), dict) else {}
    return {NODE: node, **total, **{str(k): dict(v) for k, v in (body.get("groups") or {}).items()}}


def _select(fits: dict[str, dict[str, Any]], group: str | None) -> dict[str, dict[str, Any]]:
    if group is None:
        return fits
    if group not in fits:
        raise InputError(f"--group {group}: unknown group; this daemon has {', '.join(fits)}")
    return {group: fits[group]}


def _run(args: argparse.Namespace) -> int:
    from hdeem_watch.wire.client import ControlError, DaemonUnreachable

    try:
        with _client(args) as client:
            body = client.call("calib.get")
            fits = fits_of(body)
            chosen = _select(fits, args.group)
            if args.action == "show":
                return _show(body, chosen, as_json=args.json)
            if args.action == "reset":
                if not args.yes:
                    runs = ", ".join(f"{n} {counted(e.get('runs') or 0, 'run')}" for n, e in chosen.items())
                    raise InputError(f"calib reset forgets the calibration runs ({runs}) for good; "
                                     "add --yes to confirm")
                return _reset(client, body, args.group)
            return _export(client, body, args.group, Path(args.out))
    except DaemonUnreachable as error:
        print(f"hdeem-watch calib: error: no reply from the daemon ({error})", file=sys.stderr)
        return 1
    except ControlError as error:
        print(f"hdeem-watch calib: error: the daemon refused: {error}", file=sys.stderr)
        return 1


def _show(body: dict[str, Any], chosen: dict[str, dict[str, Any]], *, as_json: bool) -> int:
    alarms = [a for a in body.get("alarms") or [] if a.get("group") in chosen]
    skipped = [{**s, "group": NODE} for s in body.get("node_skipped") or []] if NODE in chosen else []
    skipped += [s for s in body.get("skipped") or [] if s.get("group") in chosen]
    if as_json:
        out = {"memspec": body.get("memspec"), "node": chosen.get(NODE),
               "groups": {k: v for k, v in chosen.items() if k != NODE}, "alarms": alarms, "skipped": skipped}
        print(json.dumps(out, allow_nan=False))
        return 0
    print(format_fits(chosen, alarms, skipped))
    return 0


def _ma(value: Any) -> str:
    return "—" if not isinstance(value, int | float) or not math.isfinite(value) else f"{value * 1e3:.2f}"


def format_fits(chosen: dict[str, dict[str, Any]], alarms: list[dict[str, Any]], skipped: list[dict[str, Any]]) -> str:
    """The human-readable ``calib show``: one block per fit (each current with its 95 % interval
    in mA, or "no interval" where the fit gives none), then the alarms and skipped runs."""
    lines = []
    missing_interval = False
    for name, entry in chosen.items():
        if not entry.get("fit"):
            lines.append(f"{name}: no fit yet ({counted(entry.get('runs') or 0, 'run')})")
            continue
        fit = FitRecord.from_dict(entry["fit"])
        loo_text = "—" if math.isnan(fit.error.loo) else f"{fit.error.loo * 100:.2f} %"
        lines.append(f"{name}: {counted(fit.n_runs, 'run')}, status {fit.status}, leave-one-out {loo_text}")
        lines.extend(trust_lines(fit))
        for current, c in fit.currents.items():
            lo, hi = c.ci95_a
            flags = "" if c.identifiable else "  not determined"
            flags += f"  at {c.at_bound} bound" if c.at_bound else ""
            interval = f"[{_ma(lo)}, {_ma(hi)}]" if "—" not in (_ma(lo), _ma(hi)) else "no interval"
            missing_interval = missing_interval or interval == "no interval"
            lines.append(f"  {current:<6} {_ma(c.calibrated_a):>8} mA  {interval:<17}  "
                         f"datasheet {_ma(c.datasheet_a)}{flags}")
        lines.extend(socket_lines(fit))
    if missing_interval:
        lines.append("no interval: the fit gives none for that current (too few runs for it to be determined)")
    for a in alarms:
        lines.append(f"ALARM {a.get('group')} {a.get('current')} ({a.get('kind')}, {a.get('direction')}): "
                     f"{a.get('statistic')} > {a.get('threshold')}")
    for s in skipped[-5:]:
        lines.append(f"not fitted: {s.get('reason')}")
    return "\n".join(lines)


def socket_lines(fit: FitRecord) -> list[str]:
    """Each socket's own value of every current, for a node fitted per socket (its currents are the
    sockets' mean over the DIMMs: a spread between the sockets is the parts', not noise)."""
    sockets = fit.per_socket
    if not sockets:
        return []
    lines = ["  per socket (mA; the node's value is their mean over the DIMMs; * = not determined there):"]
    for current in fit.currents:
        cells = []
        for sensor, values in sockets.items():
            value, determined = values.get(current, (math.nan, False))
            cells.append(f"{sensor} {_ma(value):>8}{' ' if determined else '*'}")
        lines.append(f"    {current:<6} " + "  ".join(cells).rstrip())
    return lines


COMMAND_SOURCES = {"counted": "commands counted in each run's window (memory-controller counters)",
                   "modelled": "commands from the kernel model (no counters)",
                   "mixed": "commands counted where the runs had counters, else modelled"}


def trust_lines(fit: FitRecord) -> list[str]:
    """What a fit rests on: its command source, held currents, currents the modelled commands leave open."""
    if fit.trust is None:
        return []
    lines = [f"  commands: {COMMAND_SOURCES.get(str(fit.commands), str(fit.commands))}"]
    for current, held in fit.held.items():
        lo, hi = held.range_a
        lines.append(f"  {current} held at {_ma(held.value_a)} mA (datasheet scaled like {held.anchor}; "
                     f"no run shows its state; range [{_ma(lo)}, {_ma(hi)}] carried into the others)")
    if fit.unconfirmed:
        lines.append(f"  rest on modelled activations nothing confirms: {', '.join(fit.unconfirmed)}")
    return lines


def _reset(client: Any, body: dict[str, Any], group: str | None) -> int:
    if group is not None and group != NODE and not body.get("groups"):
        raise InputError(f"--group {group}: this daemon keeps no per-group fits; 'calib reset' without "
                         "--group resets its node fit")
    reply = client.call("calib.reset", {"group": group} if group else {})
    after = fits_of(reply)
    names = [group] if group else list(after)
    print(f"calibration reset: {', '.join(names)} "
          f"({', '.join(str((after.get(n) or {}).get('runs') or 0) for n in names)} runs left)")
    return 0


def _export(client: Any, body: dict[str, Any], group: str | None, out: Path) -> int:
    from hdeem_watch.dram.energy import CURRENT_NAMES

    memspec = body.get("memspec")
    if not isinstance(memspec, str) or not memspec:
        raise InputError("calib export: the daemon names no memspec")
    spec_path = Path(memspec)
    if spec_path.is_file():
        memspec = str(spec_path.resolve())
    fit = (fits_of(body).get(group or NODE) or {}).get("fit") or {}
    fitted = {str(r.get("name")) for r in fit.get("runs") or []}
    runs: list[dict[str, Any]] = []
    refused: list[dict[str, Any]] = []
    before = None
    while True:
        page = client.call("runs.list", {"full": True, "limit": 20, **({"before": before} if before else {})})
        for record in page.get("runs") or []:
            row = _row_of(record, group)
            if row is not None and str(row.get("name")) in fitted:
                runs.append(_run_entry(record, row, CURRENT_NAMES))
            elif record.get("state") == "done":
                refused.append({"name": f"{record.get('run_id')}:{record.get('name')}",
                                "reason": str(record.get("model_error") or "not in the daemon's current fit "
                                              "(forgotten, or fitted before a reset)")})
        before = page.get("next_before")
        if not before:
            break
    if not runs:
        where = f" of group {group}" if group else ""
        raise InputError(f"calib export: the daemon's fit{where} holds no runs ({len(refused)} finished runs not "
                         "fitted, e.g. after calib reset); nothing to export")
    runs.reverse()  # oldest first
    refused.reverse()
    calibration = {"currents": list((fit.get("currents") or {}).keys()),
                   "trust": isinstance(fit.get("trust"), dict)}
    try:
        out.write_text(json.dumps({"memspec": memspec, "calibration": calibration, "runs": runs,
                                   "not_fitted": refused}, indent=1) + "\n", encoding="utf-8")
    except OSError as error:
        raise InputError(f"--out {out}: cannot write: {error.strerror or error}") from None
    print(f"{counted(len(runs), 'fitted run')} written to {out} (hdeem-watch calibrate --runs {out}); "
          f"{counted(len(refused), 'run')} not fitted listed under not_fitted")
    return 0


def _row_of(record: dict[str, Any], group: str | None) -> dict[str, Any] | None:
    model = record.get("model") or {}
    if record.get("state") != "done":
        return None
    if group in (None, NODE):
        row = model.get("observation")
    else:
        row = (model.get("group_observations") or {}).get(group)
    return row if isinstance(row, dict) and row.get("columns") else None


def _run_entry(record: dict[str, Any], row: dict[str, Any], names: tuple[str, ...]) -> dict[str, Any]:
    columns = list(row["columns"])
    entry: dict[str, Any] = {"name": str(row.get("name") or record.get("run_id")),
                             "measured_j": float(row["measured_j"]),
                             "columns": {n: float(c) for n, c in zip(names, columns)},
                             "constant_j": float(row.get("constant_j") or 0.0),
                             "time_ns": int(row.get("time_ns") or 0)}
    if row.get("window_s") is not None:
        entry["window_s"] = float(row["window_s"])
    if row.get("commands"):
        entry["commands"] = str(row["commands"])
    if row.get("act_columns") is not None:
        entry["act_columns"] = {n: float(c) for n, c in zip(names, row["act_columns"]) if c}
    if row.get("act_factors"):
        entry["act_factors"] = [float(f) for f in row["act_factors"]]
    return entry
