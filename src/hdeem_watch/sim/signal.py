"""The simulated node's noise-free signal: each channel's mean power over its sample intervals.

Pure functions of the idle power per DIMM, the active :class:`~hdeem_watch.sim.model.RunPlan`
objects and the channel's board offset. A sample ending at ``t`` is the mean power over
``(t − period, t]``; a run adds its DRAM excess over the overlap of that interval with its traffic
and its cores' power over the overlap with its CPU load (threads fill socket 0 first). A sensor
reads ``gain × power + offset`` (its own gain and offset).

Example:
    >>> import numpy as np
    >>> idle = np.full(8, 0.5)
    >>> channel_power_w("DDR_AB", np.array([10, 20]), 10, idle, [], offset_w=0.25).tolist()
    [1.25, 1.25]
    >>> float(flat_power_w(idle, dict.fromkeys(TAURUS.channels, 0.0))["BLADE"])
    69.0
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

import numpy as np

from hdeem_watch.sim.jobs import JobPlan
from hdeem_watch.sim.layout import TAURUS, SimLayout
from hdeem_watch.sim.model import RunPlan

#: A run's plan or an opaque job's.
Plan = RunPlan | JobPlan

#: Idle CPU package power (W) per socket and the extra power per busy core / hyper-thread.
CPU_IDLE_W = (12.0, 8.0)
CPU_CORE_W = 1.5
CPU_HT_W = 0.3
#: Blade power not in the VR sensors (fans, board, disks, NIC), W.
BLADE_BASE_W = 45.0
#: Noise σ (W) per channel kind.
NOISE_W = {"blade": 0.8, "cpu": 0.25, "dram": 0.05}
#: The DIMMs (indices) behind each DIMM-pair channel of the default node.
PAIR_DIMMS = {name: TAURUS.sensor_dimms(name) for name in TAURUS.sensors}


def overlap(t_end: np.ndarray, period: int, a: int, b: float) -> np.ndarray:
    """Fraction of each interval ``(t − period, t]`` that lies inside ``(a, b]``."""
    lo = np.maximum(t_end - period, a)
    hi = np.minimum(t_end.astype(float), b)
    return np.clip(hi - lo, 0.0, None) / period


def dram_w(dimms: list[int], t_end: np.ndarray, period: int, idle_w: np.ndarray, plans: Iterable[Plan]) -> np.ndarray:
    """Mean power of ``dimms`` over each interval: idle plus every run's excess while its traffic flows."""
    power = np.full(len(t_end), float(idle_w[dimms].sum()))
    for plan in plans:
        if isinstance(plan, JobPlan):
            power += plan.dram_w(dimms, t_end, period)
            continue
        if plan.duration_ns <= 0:
            continue
        excess = float(plan.excess_w[dimms].sum())
        power += excess * overlap(t_end, period, plan.t0_ns, plan.traffic_end_ns)
    return power


def cpu_idle_w(socket: int) -> float:
    """Idle package power of ``socket`` (W): socket 0 carries the OS, the others idle lower."""
    return CPU_IDLE_W[min(socket, len(CPU_IDLE_W) - 1)]


def cpu_w(socket: int, t_end: np.ndarray, period: int, plans: Iterable[Plan], cores: int = 12) -> np.ndarray:
    """Mean package power of ``socket`` over each interval: idle plus the busy cores of every run."""
    power = np.full(len(t_end), cpu_idle_w(socket))
    for plan in plans:
        n = plan.threads[socket] if socket < len(plan.threads) else 0
        if n <= 0:
            continue
        extra = CPU_CORE_W * min(n, cores) + CPU_HT_W * max(n - cores, 0)
        end = math.inf if plan.cpu_end_ns is None else plan.cpu_end_ns
        power += extra * overlap(t_end, period, plan.t0_ns, end)
    return power


def channel_power_w(name: str, t_end: np.ndarray, period: int, idle_w: np.ndarray, plans: Iterable[Plan],
                    *, offset_w: float, layout: SimLayout = TAURUS, gain: float = 1.0) -> np.ndarray:
    """Noise-free reading of channel ``name`` over each interval ``(t − period, t]``: ``gain`` × its
    mean power + ``offset_w`` (W)."""
    plans = list(plans)
    cores = layout.topology.cores_per_socket
    if name in layout.sensors:
        power = dram_w(layout.sensor_dimms(name), t_end, period, idle_w, plans)
    elif name in layout.cpu_channels:
        power = cpu_w(int(name[3:]), t_end, period, plans, cores)
    else:  # BLADE: base + every socket + all DIMMs
        power = BLADE_BASE_W + cpu_w(0, t_end, period, plans, cores)
        for socket in range(1, layout.sockets):
            power = power + cpu_w(socket, t_end, period, plans, cores)
        power = power + dram_w(list(range(len(layout.dimm_names))), t_end, period, idle_w, plans)
    return power * gain + offset_w if gain != 1.0 else power + offset_w


def mean_power_w(name: str, a: int, b: int, idle_w: np.ndarray, plans: Iterable[Plan], *, offset_w: float,
                 layout: SimLayout = TAURUS, gain: float = 1.0) -> float:
    """Noise-free mean power of ``name`` over ``(a, b]`` (for samples lost to the sensor buffer)."""
    if b <= a:
        return 0.0
    return float(channel_power_w(name, np.array([b], dtype=np.int64), b - a, idle_w, plans, offset_w=offset_w,
                                 layout=layout, gain=gain)[0])


def flat_power_w(idle_w: np.ndarray, offset_w: Mapping[str, float], layout: SimLayout = TAURUS,
                 gain: Mapping[str, float] | None = None) -> dict[str, float]:
    """Noise-free reading of every channel of an idle node (W), summed as :func:`channel_power_w` sums."""
    g = gain if gain is not None else dict.fromkeys(offset_w, 1.0)
    flat = {name: float(idle_w[layout.sensor_dimms(name)].sum()) * g[name] + offset_w[name] for name in layout.sensors}
    cpu_total = 0.0
    for socket, name in enumerate(layout.cpu_channels):
        flat[name] = cpu_idle_w(socket) * g[name] + offset_w[name]
        cpu_total += cpu_idle_w(socket)
    flat["BLADE"] = (BLADE_BASE_W + cpu_total + float(idle_w.sum())) * g["BLADE"] + offset_w["BLADE"]
    return flat


def deposit_owed(owed: list[tuple[int, float]], t_end: np.ndarray, period: int,
                 power_w: np.ndarray, room_w: np.ndarray | float = math.inf) -> list[tuple[int, float]]:
    """Add energy owed by stopped runs, ``[(sim ns of the stop, J)]``, to the samples ending at or after
    each stop (``power_w`` in place), at most ``room_w`` more watts per sample (what a sensor can
    still read: the pair's physical maximum minus its power), the rest to the following samples; return
    what is still owed after ``t_end`` (stamped at its last sample, so the next batch continues). The
    energy is exact: every joule owed is deposited once.

    >>> power = np.array([1.0, 1.0, 1.0])
    >>> deposit_owed([(0, 10.0)], np.array([1, 2, 3]) * 10**9, 10**9, power, room_w=3.0), power.tolist()
    ([(3000000001, 1.0)], [4.0, 4.0, 4.0])
    """
    if not len(t_end):
        return list(owed)
    room = np.broadcast_to(np.asarray(room_w, dtype=float), power_w.shape).copy()
    seconds = period * 1e-9
    keep = []
    for t_owed, joules in owed:
        if t_owed > t_end[-1]:
            keep.append((t_owed, joules))
            continue
        i = int(np.searchsorted(t_end, t_owed, side="left"))
        while joules > 0 and i < len(t_end):
            added = min(joules / seconds, max(0.0, float(room[i])))
            power_w[i] += added
            room[i] -= added
            joules -= added * seconds
            i += 1
        if joules > 1e-12:
            keep.append((int(t_end[-1]) + 1, joules))
    return keep
