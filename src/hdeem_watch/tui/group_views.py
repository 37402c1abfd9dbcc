"""The per-sensor-group part of a ``calib`` body as views: one :class:`GroupFitView` per sensor
group (and ``node``, the fit of the groups' sum), and the drift alarms (docs/calibration.md,
"Per-sensor-group fits"). Pure; a body without groups gives none.

Example:
    >>> alarms = alarm_views([{"group": "DDR_CD", "current": "energy", "kind": "residual-cusum",
    ...                        "statistic": 12.4, "threshold": 12.0, "time_ns": 5, "direction": "up"}])
    >>> alarm_text(alarms[0])
    'DDR_CD energy drifts up (residual-cusum 12.4 > 12)'
    >>> is_drift(alarms[0])
    True
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from hdeem_watch.fit_record import FitRecord
from hdeem_watch.tui.snapshot import AlarmView, CurrentView, GroupFitView

#: The name of the groups' sum (the node-level fit) beside the groups, and its key in the body.
NODE, TOTAL = "node", "total"


def _num(value: Any) -> float:
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else math.nan


def alarm_views(raw: Any) -> tuple[AlarmView, ...]:
    """The alarms of a ``calib`` body (malformed entries skipped)."""
    out = []
    for entry in raw if isinstance(raw, list) else []:
        if not isinstance(entry, Mapping) or not isinstance(entry.get("group"), str):
            continue
        time_ns = entry.get("time_ns")
        out.append(AlarmView(group=entry["group"], current=str(entry.get("current") or ""),
                             kind=str(entry.get("kind") or ""), direction=str(entry.get("direction") or ""),
                             statistic=_num(entry.get("statistic")), threshold=_num(entry.get("threshold")),
                             time_ns=int(time_ns) if isinstance(time_ns, int) else 0))
    return tuple(out)


def is_drift(alarm: AlarmView) -> bool:
    """A change over time: the residual CUSUM (the pair's energy against its own earlier runs of
    the same kind) and the sibling comparison (a current's change since the pair's reference fit
    against its siblings' changes) both are; other kinds are not."""
    return alarm.kind in ("residual-cusum", "sibling")


def alarm_text(alarm: AlarmView) -> str:
    """One line: the group, what drifts which way, and the statistic against its threshold.

    Example:
        >>> alarm_text(AlarmView("DDR_GH", "idd3n", "sibling", "up", 0.21, 0.15, 0))
        'DDR_GH idd3n drifts up vs its siblings: +21 % since its reference fit (sibling > 15 %)'
    """
    if alarm.kind == "sibling":
        return (f"{alarm.group} {alarm.current} drifts {alarm.direction} vs its siblings: "
                f"{alarm.statistic:+.0%} since its reference fit (sibling > {alarm.threshold:.0%})").replace("%", " %")
    return (f"{alarm.group} {alarm.current} drifts {alarm.direction} "
            f"({alarm.kind} {abs(alarm.statistic):.3g} > {alarm.threshold:.3g})")


def _currents(fit: FitRecord) -> tuple[CurrentView, ...]:
    return tuple(CurrentView(name=cur.name.lower(), datasheet_a=cur.datasheet_a, calibrated_a=cur.calibrated_a,
                             ci95_a=cur.half_width_a, identifiable=bool(cur.identifiable))
                 for cur in fit.currents.values())


def group_view(name: str, entry: Mapping[str, Any], alarms: tuple[AlarmView, ...]) -> GroupFitView:
    """One group's view from its ``calib`` entry."""
    fit = FitRecord.from_dict(entry["fit"]) if isinstance(entry.get("fit"), Mapping) else None
    dimms = entry.get("dimms_per_socket")
    runs = entry.get("runs")
    return GroupFitView(
        name=name,
        currents=_currents(fit) if fit is not None else (),
        runs=int(runs) if isinstance(runs, int) else 0,
        status=(fit.status or "") if fit is not None else "",
        error_loo=fit.error.loo if fit is not None else math.nan,
        dimms=sum(d for d in dimms if isinstance(d, int)) if isinstance(dimms, list) else 0,
        alarms=tuple(a for a in alarms if a.group == name),
    )


def group_views(body: Mapping[str, Any]) -> tuple[tuple[GroupFitView, ...], tuple[AlarmView, ...]]:
    """The groups (then ``node``) and the alarms of a ``calib`` body."""
    alarms = alarm_views(body.get("alarms"))
    groups = body.get("groups")
    if not isinstance(groups, Mapping) or not groups:
        return (), alarms
    views = [group_view(str(n), e, alarms) for n, e in groups.items() if isinstance(e, Mapping)]
    if isinstance(body.get(TOTAL), Mapping):
        views.append(group_view(NODE, body[TOTAL], alarms))
    return tuple(views), alarms
