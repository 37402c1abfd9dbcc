"""What the simulated node reveals about its hidden truth: the ``truth()`` report (simulation only).

The report is honest about two things: the true currents (per DIMM, per DIMM pair, and averaged;
with each pair's part factor, sensor gain and offset, temperature, refresh rate and aging state),
and what a node-level linear fit of the five calibrated currents can and cannot absorb
(``effects``). ``effective_currents_a`` is a first-order estimate of what such a fit recovers: the
core truth of the calibrated currents (the others held at their datasheet values, as the fit holds
them), plus I/O energy per burst as IDD4R/IDD4W, the difference between the node's real idle power
(power-down, refresh at its temperature) and the model's idle power as IDD2N, the IPP0 deviation as
IDD0, times the sensor gain, plus the sensor offsets as a shift of every calibrated VDD current.
The effects marked ``"no"`` are what keeps a fit a few percent off.

Example:
    >>> from hdeem_watch.sim.currents import PartCurrents
    >>> from hdeem_watch.sim.plan import TruthNode
    >>> node = TruthNode(1)
    >>> parts = PartCurrents(node.model.names, node.model.datasheet, 1, pairs=node.layout.dimm_sensor)
    >>> flat = dict.fromkeys(node.layout.channels, 0.0)
    >>> report = truth_report(node, parts, 0.0, t_ns=0, offset_w=flat, gain=dict.fromkeys(flat, 1.0))
    >>> report["simulated"], len(report["dimms"]), sorted(report["pairs"])[0]
    (True, 8, 'DDR_AB')
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from hdeem_watch.dram.stats import refresh_interval
from hdeem_watch.sim.currents import PartCurrents
from hdeem_watch.sim.model import CALIBRATED
from hdeem_watch.sim.plan import TruthNode
from hdeem_watch.sim.power import refresh_per_s

#: Each effect the sim has beyond the model, whether a node-level fit absorbs it, and why.
EFFECTS: tuple[tuple[str, str, str], ...] = (
    ("io_per_burst", "yes", "a fixed energy per read/write burst: IDD4R/IDD4W rise by it"),
    ("sensor_offset", "yes", "a constant power: every calibrated VDD current shifts"),
    ("idle_power_down", "partly", "idle ranks sit in precharge power-down (IDD2P), the model says IDD2N: "
     "absorbed by IDD2N for idle stretches, not for the precharged time of loaded ranks"),
    ("sensor_gain", "partly", "±3 % per pair: a node-level fit sees their load-weighted mean, a per-pair fit absorbs it"),
    ("part_variation", "partly", "±10 % currents per pair: a node-level fit averages the pairs by load "
     "(threads fill socket 0 first), a per-pair fit absorbs it"),
    ("row_hits", "no", "the node's page placement, channel and bank hash and batching controller give other "
     "activations per line than the model, differently per kernel and thread count"),
    ("active_power_down", "no", "ranks drop to IDD3P in gaps between requests at low request rates"),
    ("hot_refresh", "no", "refresh doubles above 85 °C; the model refreshes every tREFI"),
    ("temperature", "no", "currents follow each DIMM's temperature swing over the sim hour"),
    ("aging", "no", "a pair's currents drift over sim time (a drift detector's job, not the fit's)"),
    ("noise_and_quantisation", "no", "Gaussian sensor noise and 0.125 W steps: zero-mean error per sample"),
)


#: The currents a fit of counted windows calibrates besides :data:`CALIBRATED`: the counters measure
#: power-down residency (``hdeem_watch.calibrate.counter_model.POWERDOWN_CURRENTS``).
COUNTED_EXTRA = ("idd2p", "idd3p")


def absorbable_currents(node: TruthNode, currents: np.ndarray, temps_c: np.ndarray, gains: np.ndarray,
                        offsets_w: np.ndarray, *, counted: bool = False) -> np.ndarray:
    """Per DIMM, a first-order estimate of the currents a node-level fit of :data:`CALIBRATED` recovers.

    Args:
        node: the truth generator (spec, physics, idle power).
        currents: core truth, DIMMs × names.
        temps_c: the DIMMs' temperatures.
        gains: the sensor gain of each DIMM's pair.
        offsets_w: each DIMM's share of its pair's sensor offset (W).
        counted: the fit's rows come from the memory controller's counters: power-down residency
            is counted (IDD2P/IDD3P calibrated too), so IDD2N does not absorb the idle power-down.
    """
    model, spec = node.model, node.spec
    names = list(model.names)
    index = {n: i for i, n in enumerate(names)}
    fitted = CALIBRATED + (COUNTED_EXTRA if counted else ())
    calibrated = [index[n] for n in fitted if n in index]
    out = np.broadcast_to(model.datasheet, currents.shape).copy()
    out[:, calibrated] = currents[:, calibrated]
    burst_j_per_a = model.burst_j_per_a()
    out[:, index["idd4r"]] += node.physics.io_read_j / burst_j_per_a
    out[:, index["idd4w"]] += node.physics.io_write_j / burst_j_per_a
    out[:, index["idd0"]] += (currents[:, index["ipp0"]] - model.datasheet[index["ipp0"]]) * float(spec.vpp) / float(spec.vdd)
    if not counted:
        idle_cols, idle_const = node.model_idle_columns()
        model_idle_w = out @ idle_cols + idle_const
        out[:, index["idd2n"]] += (node.idle_power_w(currents, temps_c) - model_idle_w) / idle_cols[index["idd2n"]]
    f_ref = float(spec.trfc) / refresh_interval(spec)
    if counted:  # the fit holds IDD5B at its datasheet value: the refresh power's deviation is a constant power
        i5b = index["idd5b"]
        refresh = (currents[:, i5b] - model.datasheet[i5b]) * f_ref / (1.0 - f_ref)
        for j in calibrated:
            out[:, j] += refresh
    out[:, calibrated] *= gains[:, None]
    shift = offsets_w / (model.standby_w_per_a() * (1.0 - f_ref))
    for j in calibrated:
        if names[j].startswith("idd"):
            out[:, j] += shift
    return out


def truth_report(node: TruthNode, parts: PartCurrents, t_s: float, *, t_ns: int, offset_w: Mapping[str, float],
                 gain: Mapping[str, float], violations: Mapping[int, list[str]] | None = None) -> dict[str, Any]:
    """The hidden truth at ``t_s`` sim seconds: currents (A per device) per DIMM, per pair and averaged.

    Args:
        node: the truth generator.
        parts: the hidden currents over time.
        t_s: sim time (s since open).
        t_ns: the report's timestamp (wall ns).
        offset_w: the sensor offset of every channel (W).
        gain: the sensor gain of every channel.
        violations: the memspec check of the truth per DIMM, if already known (else checked now).
    """
    model, layout = node.model, node.layout
    names = model.names
    currents = parts.currents(t_s)
    temps = parts.temperature_c(t_s)
    ages = parts.age_factors(t_s)
    pair_of = layout.dimm_sensor
    gains = np.array([gain[p] for p in pair_of])
    offsets = np.array([offset_w[p] / len(layout.sensor_dimms(p)) for p in pair_of])
    effective = absorbable_currents(node, currents, temps, gains, offsets)
    counted = absorbable_currents(node, currents, temps, gains, offsets, counted=True)
    base_refresh = refresh_per_s(node.spec, node.physics.hot_c - 1.0)

    def by_name(values: np.ndarray) -> dict[str, float]:
        return {n: float(v) for n, v in zip(names, values)}

    pairs = {pair: _pair_truth(node, parts, pair, currents, effective, counted, temps, ages, offset_w, gain)
             for pair in layout.sensors}
    return {
        "simulated": True,
        "t_ns": t_ns,
        "t_sim_s": float(t_s),
        "backend": model.backend,
        "generator": "sim's own: page placement, channel/bank hash, batching open-page controller, power-down, "
                     "refresh by temperature, I/O per burst, per-pair parts, sensor gain/offset, aging",
        "unit": "A per device",
        "datasheet": by_name(model.datasheet),
        "mean_currents_a": by_name(currents.mean(axis=0)),
        "effective_currents_a": by_name(effective.mean(axis=0)),
        "counted_currents_a": by_name(counted.mean(axis=0)),
        "counted_note": "the same for a fit of counted windows: power-down residency is counted, so IDD2N does "
                        "not absorb the idle power-down and IDD2P/IDD3P are calibrated as well",
        "effective_note": "first-order estimate of a node-level fit: calibrated core truth + I/O per burst "
                          "(IDD4R/IDD4W) + real vs model idle power (IDD2N), × sensor gain, + sensor offsets; "
                          "the effects marked 'no' keep a fit a few percent off",
        "physical_violations": {f"DIMM_{layout.dimm_names[d]}": v
                                for d, v in (node.physical_violations(currents) if violations is None
                                             else violations).items()},
        "effects": [{"effect": e, "node_fit_absorbs": a, "why": w} for e, a, w in EFFECTS],
        "pairs": pairs,
        "aging": {pair: {"rate_per_h": float(rate), "start_s": float(parts.age_start_s[pair]),
                         "factor": float(ages[pair])} for pair, rate in parts.age.items()},
        "global_aging_per_h": float(parts.aging_per_h),
        "dimms": {
            f"DIMM_{dimm}": {
                "channel": pair_of[d], "socket": layout.dimm_socket[d], "temperature_c": float(temps[d]),
                "refresh_x": float(refresh_per_s(node.spec, float(temps[d]), node.physics.hot_c) / base_refresh),
                "currents_a": by_name(currents[d]),
            }
            for d, dimm in enumerate(layout.dimm_names)
        },
        "offsets_w": dict(offset_w),
        "gains": dict(gain),
        "io_read_j": node.physics.io_read_j,
        "io_write_j": node.physics.io_write_j,
        "io_j_per_line": (node.physics.io_read_j + node.physics.io_write_j) / 2,
        "pd_entry_s": node.physics.pd_entry_s,
    }


def _pair_truth(node: TruthNode, parts: PartCurrents, pair: str, currents: np.ndarray, effective: np.ndarray,
                counted: np.ndarray, temps: np.ndarray, ages: Mapping[str, float], offset_w: Mapping[str, float],
                gain: Mapping[str, float]) -> dict[str, Any]:
    """The truth of one DIMM pair (``pair``) for :func:`truth_report`: its currents averaged over its DIMMs.

    Args:
        node: the truth generator.
        parts: the hidden currents over time.
        pair: the sensor channel of the pair.
        currents: the true currents (A per device), one row per DIMM.
        effective: the currents a node-level fit would recover, one row per DIMM.
        counted: the same for a fit of counted windows, one row per DIMM.
        temps: the temperature of every DIMM (°C).
        ages: the aging factor of every aging pair.
        offset_w: the sensor offset of every channel (W).
        gain: the sensor gain of every channel.
    """
    layout, names = node.layout, node.model.names
    dimms = layout.sensor_dimms(pair)

    def by_name(values: np.ndarray) -> dict[str, float]:
        return {n: float(v) for n, v in zip(names, values)}

    return {
        "dimms": [f"DIMM_{layout.dimm_names[d]}" for d in dimms],
        "currents_a": by_name(currents[dimms].mean(axis=0)),
        "effective_currents_a": by_name(effective[dimms].mean(axis=0)),
        "counted_currents_a": by_name(counted[dimms].mean(axis=0)),
        "part_factor": float(parts.part_factor[pair]),
        "sensor_gain": float(gain[pair]),
        "sensor_offset_w": float(offset_w[pair]),
        "temperature_c": float(temps[dimms].mean()),
        "age_per_h": float(parts.age.get(pair, 0.0)),
        "age_start_s": float(parts.age_start_s.get(pair, 0.0)),
        "age_factor": float(ages.get(pair, 1.0)),
    }
