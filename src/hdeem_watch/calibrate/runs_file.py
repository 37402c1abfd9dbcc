"""Read RUNS.json, the input of ``hdeem-watch calibrate`` (DESIGN.md §7) — the I/O shell.

Format (paths relative to the RUNS.json file)::

    {"memspec": "M.json",                      # or "samsung-m393a1g43db0-cpb" (or "preset:...")
     "runs": [
       {"name": "triad-24", "measured_j": 41.7, "trace": "triad.csv"},
       {"name": "idle", "measured_j": 12.1, "stats": {"ranks": [{...RankStats...}, ...]},
        "window_s": 2.0, "scale": 8}
     ]}

Per run: ``name`` (default ``run[i]``), ``measured_j`` (> 0) — or, instead, ``hdeem_printout``: a
real ``checkHdeem`` / ``hdeem_get_stats`` printout whose DIMM-pair energy (DDR_AB + DDR_CD + DDR_EF +
DDR_GH) is the measured energy, with ``printout_block`` choosing which statistics-since-start block
(index among those with a DRAM energy; default the last) and its duration the default window —
exactly one of ``trace`` (a DRAMPower
command trace CSV) or ``stats`` (:meth:`CommandStats.to_dict` form), and optionally ``scale`` (how
many such channels the measured energy covers, default 1), ``window_s`` (the measured window; the
model's residency and refresh are stretched to it; default: the trace's/statistics' own window),
``time_ns`` and ``weight``.

Instead of ``trace`` or ``stats`` a run may give its calibration row as the daemon built it
(``hdeem-watch calib export`` writes these): ``columns`` (current name → J per A of the whole
measured energy, e.g. ``{"idd0": 812.5, "idd2n": 96.1, ...}``; currents not named count 0) and
``constant_j`` (the model energy that depends on no current); ``scale`` then multiplies both. Such a
row may also say where its commands came from, ``commands`` (``"counters"`` or ``"model"``), and for a
modelled row the columns its activations carry, ``act_columns``, and its activation count under the
other address-mapping families, ``act_factors`` (:mod:`hdeem_watch.calibrate.trust` uses them). A
top-level ``calibration`` object (``calib export`` writes the daemon's ``currents`` and ``trust``) sets
``hdeem-watch calibrate``'s defaults; ``not_fitted`` lists the daemon's runs it did not fit (read by
no one: the record of what was left out).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hdeem_watch.calibrate.observation import Observation, check_measured
from hdeem_watch.calibrate.rows import observation_from_run, stats_window_s
from hdeem_watch.dram.memspec import MemSpec, load_memspec, preset
from hdeem_watch.dram.presets import PRESETS
from hdeem_watch.dram.stats import CommandStats
from hdeem_watch.errors import InputError, not_a_file_error

_RUN_KEYS = {"name", "measured_j", "hdeem_printout", "printout_block", "trace", "stats", "scale", "window_s",
             "time_ns", "weight", "columns", "constant_j", "commands", "act_columns", "act_factors"}
#: Fields only a ``columns`` row may have (what ``calib export`` keeps of the daemon's row).
_ROW_ONLY = ("constant_j", "commands", "act_columns", "act_factors")


def load_spec(value: str, base: Path, where: str, *, allow_unphysical: bool = False) -> MemSpec:
    """The memspec named by ``value``: a file (relative to ``base``), else a preset by its name,
    spelled ``NAME`` or ``preset:NAME`` (a file of that name wins over a bare preset name);
    ``allow_unphysical`` loads a file whose currents break the physical ordering.

    Raises:
        InputError: an unknown preset, a missing file, or a malformed memspec (naming ``where``).
    """
    path = Path(value)
    if not path.is_absolute():
        path = base / path
    name = value.removeprefix("preset:")
    if value.startswith("preset:") or (not path.exists() and name in PRESETS):
        if name not in PRESETS:
            raise InputError(f"{where}: unknown memspec preset {name!r}; expected one of: "
                             f"{', '.join(sorted(PRESETS))}")
        return preset(name)
    if not path.is_file():
        raise InputError(f"{where}: {not_a_file_error(path, 'memspec file')} (presets: "
                         f"{', '.join(sorted(PRESETS))})")
    return load_memspec(path, allow_unphysical=allow_unphysical)


def read_runs_file(path: str | Path, memspec: str | Path | None = None, *,
                   allow_unphysical: bool = False) -> tuple[MemSpec, list[Observation]]:
    """Read RUNS.json into the memspec and one :class:`Observation` per run.

    Args:
        path: the RUNS.json file.
        memspec: a memspec overriding the file's ``memspec`` (path, or ``preset:NAME``).
        allow_unphysical: load a memspec file whose currents break the physical ordering.

    Raises:
        InputError: an unreadable or malformed file, a missing or malformed trace, a bad energy,
            scale or window — one line naming the file, the run and the field.
    """
    path = Path(path)
    where = str(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except OSError as error:
        raise InputError(f"{where}: cannot read runs file: {error.strerror or error}") from None
    except UnicodeDecodeError:
        raise InputError(f"{where}: not a UTF-8 text file; expected RUNS.json") from None
    except json.JSONDecodeError as error:
        raise InputError(f"{where}: invalid JSON at line {error.lineno} column {error.colno}: {error.msg}") from None
    if not isinstance(data, Mapping):
        raise InputError(f"{where}: expected an object with 'memspec' and 'runs'")
    base = path.resolve().parent
    if memspec is not None:
        spec = load_spec(str(memspec), Path.cwd(), "--memspec", allow_unphysical=allow_unphysical)
    else:
        value = data.get("memspec")
        if not isinstance(value, str) or not value:
            raise InputError(f"{where}: memspec: expected a path (or give --memspec)")
        spec = load_spec(value, base, f"{where}: memspec", allow_unphysical=allow_unphysical)
    runs = data.get("runs")
    if not isinstance(runs, list) or not runs:
        raise InputError(f"{where}: runs: expected a non-empty list of runs")
    return spec, [_observation(spec, run, i, base, where) for i, run in enumerate(runs)]


def _number(run: Mapping[str, Any], key: str, name: str, default: float) -> float:
    value = run.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value <= 0:
        raise InputError(f"run {name!r}: {key} = {value!r}; expected a number > 0")
    return float(value)


def _observation(spec: MemSpec, run: Any, i: int, base: Path, where: str) -> Observation:
    if not isinstance(run, Mapping):
        raise InputError(f"{where}: runs[{i}]: expected an object")
    name = run.get("name", f"run[{i}]")
    if not isinstance(name, str) or not name:
        raise InputError(f"{where}: runs[{i}].name: {name!r}; expected a non-empty string")
    unknown = sorted(set(run) - _RUN_KEYS)
    if unknown:
        raise InputError(f"run {name!r}: unknown field {unknown[0]!r}; expected some of {sorted(_RUN_KEYS)}")
    printout_window = math.nan
    if "hdeem_printout" in run:
        if "measured_j" in run:
            raise InputError(f"run {name!r}: give measured_j or hdeem_printout, not both")
        measured, printout_window = _printout_energy(run, name, base)
    elif "measured_j" not in run:
        raise InputError(f"run {name!r}: measured_j missing; expected the measured energy in J (or hdeem_printout)")
    else:
        measured = check_measured(name, run["measured_j"])
    if "columns" in run:
        if "trace" in run or "stats" in run:
            raise InputError(f"run {name!r}: give columns, trace or stats, not several")
        return _row_observation(run, name, measured, printout_window)
    for key in _ROW_ONLY:
        if key in run:
            raise InputError(f"run {name!r}: {key} belongs to a 'columns' row")
    has_trace, has_stats = "trace" in run, "stats" in run
    if has_trace == has_stats:
        raise InputError(f"run {name!r}: expected exactly one of 'trace' (a path), 'stats' (an object) "
                         "or 'columns' (a model row)")
    if has_trace:
        stats = _trace_stats(spec, run["trace"], name, base)
    else:
        try:
            stats = CommandStats.from_dict(run["stats"], where=f"run {name!r}: stats")
        except InputError:
            raise
        except (TypeError, AttributeError):
            raise InputError(f"run {name!r}: stats: expected an object with a list 'ranks'") from None
        if len(stats.ranks) != spec.nbr_of_ranks:
            raise InputError(f"run {name!r}: stats has {len(stats.ranks)} ranks; memspec "
                             f"{spec.memory_id!r} has {spec.nbr_of_ranks}")
    scale = _number(run, "scale", name, 1.0)
    weight = run.get("weight", 1.0)
    time_ns = run.get("time_ns", 0)
    if isinstance(time_ns, bool) or not isinstance(time_ns, int):
        raise InputError(f"run {name!r}: time_ns = {time_ns!r}; expected an integer (ns)")
    default_window = stats_window_s(spec, stats)
    if "window_s" in run:
        window = _number(run, "window_s", name, 1.0)
    elif math.isfinite(printout_window) and printout_window > 0:
        window = printout_window
    elif math.isnan(default_window):
        raise InputError(f"run {name!r}: the statistics have no window (cycles_total = 0); give window_s")
    else:
        window = default_window
    return observation_from_run(spec, stats, window, measured, scale=scale, name=name, time_ns=time_ns,
                                weight=weight)


def _row_observation(run: Mapping[str, Any], name: str, measured: float, printout_window: float) -> Observation:
    """A run given as a model row (``columns`` by current name, ``constant_j``)."""
    from hdeem_watch.dram.energy import CURRENT_NAMES

    columns = run["columns"]
    constant = run.get("constant_j", 0.0)
    if isinstance(constant, bool) or not isinstance(constant, int | float) or not math.isfinite(constant):
        raise InputError(f"run {name!r}: constant_j = {constant!r}; expected a finite number (J)")
    scale = _number(run, "scale", name, 1.0)
    time_ns = run.get("time_ns", 0)
    if isinstance(time_ns, bool) or not isinstance(time_ns, int):
        raise InputError(f"run {name!r}: time_ns = {time_ns!r}; expected an integer (ns)")
    window = _number(run, "window_s", name, 1.0) if "window_s" in run else printout_window
    commands = run.get("commands", "")
    if commands not in ("", "counters", "model"):
        raise InputError(f"run {name!r}: commands = {commands!r}; expected 'counters' or 'model'")
    act = None
    if "act_columns" in run:
        act = _current_row(run["act_columns"], name, "act_columns", CURRENT_NAMES) * scale
    factors = run.get("act_factors", [])
    if not isinstance(factors, list) or any(isinstance(f, bool) or not isinstance(f, int | float) or not f >= 0
                                            for f in factors):
        raise InputError(f"run {name!r}: act_factors = {factors!r}; expected a list of numbers >= 0")
    return Observation(name=name, columns=_current_row(columns, name, "columns", CURRENT_NAMES) * scale,
                       constant_j=float(constant) * scale, measured_j=measured, time_ns=time_ns,
                       weight=run.get("weight", 1.0), window_s=window, commands=str(commands), act_columns=act,
                       act_factors=tuple(float(f) for f in factors))


def _current_row(values: Any, name: str, field: str, names: Sequence[str]) -> np.ndarray:
    """An object of current name → number as a row over ``names`` (currents not named are 0; an
    empty ``act_columns`` is a row without activations)."""
    if not isinstance(values, Mapping) or (not values and field == "columns"):
        raise InputError(f"run {name!r}: {field}: expected an object of current name -> J per A")
    row = dict.fromkeys(names, 0.0)
    for key, value in values.items():
        if str(key).lower() not in row:
            raise InputError(f"run {name!r}: {field}.{key}: unknown current; expected some of {', '.join(names)}")
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise InputError(f"run {name!r}: {field}.{key} = {value!r}; expected a finite number (J per A)")
        row[str(key).lower()] = float(value)
    return np.array([row[n] for n in names])


def read_calibration_settings(path: str | Path) -> dict[str, Any]:
    """The ``calibration`` object ``calib export`` writes beside the runs (the daemon's calibrated
    ``currents`` and whether its fit widened the intervals, ``trust``); ``{}`` when absent or unreadable
    (:func:`read_runs_file` reports a broken file)."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return {}
    settings = data.get("calibration") if isinstance(data, Mapping) else None
    return dict(settings) if isinstance(settings, Mapping) else {}


def _trace_stats(spec: MemSpec, value: Any, name: str, base: Path) -> CommandStats:
    from hdeem_watch.dram.command_trace import read_command_trace
    from hdeem_watch.dram.trace_state import trace_stats

    if not isinstance(value, str) or not value:
        raise InputError(f"run {name!r}: trace = {value!r}; expected a path to a DRAMPower CSV trace")
    path = Path(value)
    if not path.is_absolute():
        path = base / path
    if not path.is_file():
        raise InputError(f"run {name!r}: trace: {not_a_file_error(path, 'DRAMPower trace file')}")
    try:
        return trace_stats(spec, read_command_trace(path))
    except InputError as error:
        raise InputError(f"run {name!r}: {error}") from None


def _printout_energy(run: Mapping[str, Any], name: str, base: Path) -> tuple[float, float]:
    """``(measured_j, duration_s)`` of the chosen statistics block of a real HDEEM printout."""
    from hdeem_watch.calibrate.hdeem_printout import read_printout

    value = run["hdeem_printout"]
    if not isinstance(value, str) or not value:
        raise InputError(f"run {name!r}: hdeem_printout = {value!r}; expected a path to a checkHdeem/get_stats printout")
    path = Path(value) if Path(value).is_absolute() else base / value
    if not path.is_file():
        raise InputError(f"run {name!r}: hdeem_printout: {not_a_file_error(path, 'HDEEM printout file')}")
    try:
        printout = read_printout(path)
    except InputError as error:
        raise InputError(f"run {name!r}: {error}") from None
    blocks = [b for b in printout.of_kind("stats") if math.isfinite(b.dram_energy_j())]
    if not blocks:
        raise InputError(f"run {name!r}: {path}: no statistics block with DDR_AB..DDR_GH energies")
    index = run.get("printout_block", len(blocks) - 1)
    if isinstance(index, bool) or not isinstance(index, int) or not -len(blocks) <= index < len(blocks):
        raise InputError(f"run {name!r}: printout_block = {index!r}; expected an index below {len(blocks)}")
    block = blocks[index]
    return check_measured(name, block.dram_energy_j()), float(block.duration_s)
