"""Calibration of the DRAM model's currents against measured energies (DESIGN.md §4).

Public names (the contract other areas build on):

- :class:`Observation`, :func:`observation_from_run` — a measured run as a linear equation;
  :func:`node_observation` — one row for a whole node's channel groups;
- :func:`fit` (:class:`FitOptions`) → :class:`FitResult` (``to_dict()`` is the JSON contract of ``calibrate --json``);
- :class:`OnlineCalibrator` — refit per run, half-life forgetting, drift, persistence;
- :func:`suggest_next` — which candidate run best determines the weakest current;
- :class:`GroupCalibrators` (:class:`SensorGroup`, :func:`sensor_groups`, :class:`MeasuredRun`,
  :func:`measured_run`) — one fit per sensor group beside the node's, guard rails, and
  :class:`DriftAlarm` s from the drift and sibling detectors.

Pure: nothing in this package reads files or clocks except :mod:`~hdeem_watch.calibrate.runs_file`
(the RUNS.json reader used by the command line).
"""

from hdeem_watch.calibrate.drift import DriftAlarm
from hdeem_watch.calibrate.fit import FitOptions, fit
from hdeem_watch.calibrate.group_rows import MeasuredRun, SensorGroup, measured_run, sensor_groups
from hdeem_watch.calibrate.groups import GroupCalibrators
from hdeem_watch.calibrate.observation import DEFAULT_CURRENTS, Observation
from hdeem_watch.calibrate.observe import posterior_relative_sd, suggest_next, weakest_current
from hdeem_watch.calibrate.online import OnlineCalibrator
from hdeem_watch.calibrate.result import FitResult, FitSettings
from hdeem_watch.calibrate.rows import node_observation, observation_from_run

__all__ = [
    "DEFAULT_CURRENTS",
    "DriftAlarm",
    "FitOptions",
    "FitResult",
    "FitSettings",
    "GroupCalibrators",
    "MeasuredRun",
    "Observation",
    "OnlineCalibrator",
    "SensorGroup",
    "fit",
    "measured_run",
    "node_observation",
    "observation_from_run",
    "posterior_relative_sd",
    "sensor_groups",
    "suggest_next",
    "weakest_current",
]
