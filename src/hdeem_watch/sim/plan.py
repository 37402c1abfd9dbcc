"""The simulated node's truth generator: a run's energy per DIMM from the sim's own controller and DIMM states.

The chain is the sim's own, not the daemon's model path (:mod:`hdeem_watch.dram.node` and the
calibration rows): traffic → page placement, channel and bank hash, batching open-page controller
(:mod:`hdeem_watch.sim.traffic`) → per-rank commands, power-down, temperature-dependent
refresh (:mod:`hdeem_watch.sim.power`) → DRAMPower's per-command energies at each DIMM's
own hidden currents, plus I/O per burst. Only the node's bandwidth (how long a run's traffic lasts,
:func:`~hdeem_watch.sim.model.modelled_line_rate`) is shared with the demo's schedule, which
holds each run for that time.

Example:
    >>> import numpy as np
    >>> from hdeem_watch.sim.currents import PartCurrents
    >>> node = TruthNode(seed=1)
    >>> parts = PartCurrents(node.model.names, node.model.datasheet, 1)
    >>> plan = node.plan(parts.currents(0.0), parts.temperature_c(0.0), "r", 0, "read", 1 << 22, 12, 5)
    >>> bool(np.all(plan.excess_w[:4] > 0)), bool(np.all(plan.excess_w[4:] == 0))
    (True, True)
"""

from __future__ import annotations

import numpy as np

from hdeem_watch.dram.kernels import access_pattern, kernel_iterations
from hdeem_watch.dram.stats import CommandStats
from hdeem_watch.sim.layout import TAURUS, SimLayout
from hdeem_watch.sim.model import RunPlan, kernel_traffic_lines, load_model, modelled_line_rate
from hdeem_watch.sim.power import PowerPhysics, busy_rank, idle_columns, split_columns
from hdeem_watch.sim.traffic import socket_row_outcomes


class TruthNode:
    """The sim's DIMMs as they really behave: idle power and run plans from the sim's own generator.

    Args:
        seed: the node's seed (page placement).
        layout: the node's sockets, channels and sensors.
        physics: power-down, refresh and I/O parameters.
    """

    def __init__(self, seed: int = 0, layout: SimLayout = TAURUS, physics: PowerPhysics | None = None) -> None:
        self.seed = int(seed)
        self.layout = layout
        self.model = load_model(layout)
        self.spec = self.model.spec
        self.physics = physics or PowerPhysics()
        self._idle = {hot: idle_columns(self.spec, hot) for hot in (False, True)}
        self._model_idle: tuple[np.ndarray, float] | None = None

    def model_idle_columns(self) -> tuple[np.ndarray, float]:
        """The model's idle DIMM per second (precharged standby, a refresh every tREFI): columns, constant."""
        if self._model_idle is None:
            self._model_idle = self.model.linear(self.model.idle_stats(1.0))
        return self._model_idle

    def idle_power_w(self, currents: np.ndarray, temps_c: np.ndarray) -> np.ndarray:
        """Idle power (W) per DIMM for per-DIMM ``currents`` (DIMMs × names) at ``temps_c``."""
        cool, cool_k = self._idle[False]
        hot, hot_k = self._idle[True]
        is_hot = np.asarray(temps_c) > self.physics.hot_c
        cols = np.where(is_hot[:, None], hot[None, :], cool[None, :])
        return np.asarray(np.einsum("dn,dn->d", currents, cols) + np.where(is_hot, hot_k, cool_k), dtype=float)

    def physical_violations(self, currents: np.ndarray) -> dict[int, list[str]]:
        """Per DIMM whose ``currents`` break a rule of :mod:`hdeem_watch.dram.memspec_check`, the broken rules."""
        from hdeem_watch.dram.memspec_check import physical_violations

        names = self.model.names
        out = {}
        for d, row in enumerate(np.asarray(currents, dtype=float)):
            problems = physical_violations(self.spec.with_currents(dict(zip(names, map(float, row), strict=True))))
            if problems:
                out[d] = problems
        return out

    def dimm_stats(self, kernel: str, elements: int, threads: int, repeat: int, duration_s: float,
                   temps_c: np.ndarray) -> list[CommandStats | None]:
        """Per DIMM, its statistics over the run's traffic (``None`` for a DIMM without traffic)."""
        layout, spec = self.layout, self.spec
        counts = layout.topology.threads_per_socket(threads)
        width = len(access_pattern(kernel))
        out: list[CommandStats | None] = [None] * len(layout.dimm_names)
        for socket, n_threads in enumerate(counts):
            n_elements = round(int(elements) * n_threads / threads) if threads > 0 else 0
            if n_threads <= 0 or n_elements <= 0:
                continue
            requests = float(kernel_iterations(kernel, n_elements) * width * repeat)
            rows = socket_row_outcomes(spec, kernel, n_elements, n_threads, layout.topology.channels_per_socket,
                                       seed=self.seed, socket=socket)
            dimms = [d for d, s in enumerate(layout.dimm_socket) if s == socket]
            for channel, d in enumerate(dimms):
                share, writes, acts = rows.requests[channel], rows.writes[channel], rows.activations[channel]
                lines = requests * float(share.sum())
                out[d] = CommandStats(ranks=tuple(
                    busy_rank(spec, duration_s, float(temps_c[d]), requests * float(share[r] - writes[r]),
                              requests * float(writes[r]), requests * float(acts[r]), lines, self.physics)
                    for r in range(share.size)))
        return out

    def plan(self, currents: np.ndarray, temps_c: np.ndarray, run_id: str, t0_ns: int, kernel: str, elements: int,
             threads: int, repeat: int) -> RunPlan:
        """The energy plan of a run starting at ``t0_ns`` with the DIMMs' ``currents`` and temperatures then."""
        idle = self.idle_power_w(currents, temps_c)
        layout = self.layout
        tps = layout.topology.threads_per_socket(threads)
        traffic = kernel_traffic_lines(kernel, elements)
        zeros = np.zeros(len(layout.dimm_names))
        rate = modelled_line_rate(kernel, threads, int(elements), layout) if traffic is not None else 0.0
        if traffic is None or repeat <= 0 or sum(traffic) == 0 or threads <= 0 or rate <= 0:
            return RunPlan(run_id, t0_ns, 0, zeros, zeros, zeros, idle, tps, t0_ns)
        duration_s = float(sum(traffic) * repeat) / rate
        bg, dyn, io = idle.copy(), zeros.copy(), zeros.copy()
        hidden = self.dimm_stats(kernel, elements, threads, repeat, duration_s, temps_c)
        for d, stats in enumerate(hidden):
            if stats is None:
                continue
            bg_cols, cmd_cols, const = split_columns(self.spec, stats)
            bg[d] = (float(currents[d] @ bg_cols) + const) / duration_s
            dyn[d] = float(currents[d] @ cmd_cols)
            io[d] = (self.physics.io_read_j * stats.total("rd") + self.physics.io_write_j * stats.total("wr"))
        d_ns = max(1, round(duration_s * 1e9))
        return RunPlan(run_id, t0_ns, d_ns, bg, dyn, io, idle, tps, t0_ns + d_ns, stats=tuple(hidden))
