"""What the simulated node reveals about its hidden truth: the ``truth()`` report (simulation only).

``mean_currents_a`` is the core truth; ``effective_currents_a`` is what a node-level fit can recover
(:func:`~hdeem_watch.sources.sim_model.effective_currents`: the core truth plus the I/O energy per
burst as an IDD4R/IDD4W equivalent and the DIMM-pair sensor offsets as a shift of every VDD state
current), averaged over the DIMMs; compare a fit with it.

Example:
    >>> from hdeem_watch.sources.sim_model import TruthModel, load_model
    >>> model = load_model()
    >>> truth = TruthModel(model.names, model.datasheet, 1)
    >>> offsets = dict.fromkeys(("BLADE", "CPU0", "CPU1", "DDR_AB", "DDR_CD", "DDR_EF", "DDR_GH"), 0.0)
    >>> report = truth_report(model, truth, 0.0, t_ns=0, offset_w=offsets, io_j_per_line=0.0)
    >>> report["simulated"], len(report["dimms"])
    (True, 8)
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from hdeem_watch.sources.sim_model import Model, TruthModel, effective_currents


def truth_report(model: Model, truth: TruthModel, t_s: float, *, t_ns: int, offset_w: Mapping[str, float],
                 io_j_per_line: float) -> dict[str, Any]:
    """The hidden true currents at ``t_s`` sim seconds (A per device), per DIMM and averaged.

    Args:
        model: the DRAM model (names, datasheet).
        truth: the hidden currents' model.
        t_s: sim time (s since open).
        t_ns: the report's timestamp (wall ns).
        offset_w: the board offset of every channel (W).
        io_j_per_line: the sim's I/O energy per line (J).
    """
    currents = truth.currents(t_s)
    temps = truth.temperature_c(t_s)
    names = model.names
    layout = model.layout
    offsets = float(sum(offset_w[c] for c in layout.sensors))
    effective = effective_currents(model, currents, io_j_per_line, offsets)
    return {
        "simulated": True,
        "t_ns": t_ns,
        "backend": model.backend,
        "unit": "A per device",
        "datasheet": {n: float(v) for n, v in zip(names, model.datasheet)},
        "mean_currents_a": {n: float(v) for n, v in zip(names, currents.mean(axis=0))},
        "effective_currents_a": {n: float(v) for n, v in zip(names, effective.mean(axis=0))},
        "effective_note": "core truth + I/O energy per burst (IDD4R/IDD4W) + DIMM-pair sensor offsets",
        "dimms": {
            f"DIMM_{dimm}": {
                "channel": layout.dimm_sensor[d], "socket": layout.dimm_socket[d], "temperature_c": float(temps[d]),
                "currents_a": {n: float(v) for n, v in zip(names, currents[d])},
            }
            for d, dimm in enumerate(layout.dimm_names)
        },
        "offsets_w": dict(offset_w),
        "io_j_per_line": io_j_per_line,
    }
