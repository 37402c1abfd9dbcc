"""The global method's reader: new samples of the measurement's buffer, on the measured sample grids.

Each :meth:`GlobalReader.collect` reads the status (``start_time_blade``), the statistics since start
(counts and read times, for the measured periods, :mod:`hdeem_watch.sources.hdeem_timing`) and the
buffer (``hdeem_get_global``), and returns the samples not returned before. Samples are indexed since
the measurement's start: the buffer's first blade sample is ``first_blade_value`` (1-based), so a
buffer that dropped samples not yet returned shows as a gap of exactly that many; a new start time
is a new measurement, counted from 0 again. VR samples are assumed held from the start (public code
shows no ``first_vr_value``).
"""

from __future__ import annotations

import numpy as np

from hdeem_watch.sources.hdeem_lib import ShimLib
from hdeem_watch.sources.hdeem_timing import VR_OFFSET_NS, measured_periods_ns, sample_end_times_ns

Samples = dict[str, tuple[np.ndarray, np.ndarray]]


class GlobalReader:
    """Incremental reader of one connection's global buffer.

    Args:
        lib: the loaded shim (built with the status-times and global sets).
        names: sensor names, blade sensors first.
        nblade: how many of them are blade sensors.
    """

    def __init__(self, lib: ShimLib, names: list[str], nblade: int) -> None:
        self.lib, self.names, self.nblade = lib, names, nblade
        self.next_index = [0, 0]
        self.start_ns: int | None = None
        #: measured sampling periods (blade, VR) in ns, None until first measured
        self.periods_ns: tuple[float, float] | None = None

    def measure(self, handle: int, start_ns: int) -> tuple[float, float]:
        """The sampling periods measured since ``start_ns`` (``hdeem_get_stats``' counts and read times)."""
        stats = self.lib.stats(handle, False, len(self.names))
        self.periods_ns = measured_periods_ns(start_ns, stats.counts, stats.read_ns)
        return self.periods_ns

    def collect(self, handle: int, energy_j: dict[str, float]) -> tuple[Samples, dict[str, int]]:
        """The samples not returned yet and the samples known lost, per sensor; adds their energy
        (finite samples × the measured period) to ``energy_j``.

        Raises:
            HdeemError: a library call failed.
        """
        status = self.lib.status(handle)
        assert status.start_ns is not None, "the global method needs the status-times set"
        if status.start_ns != self.start_ns:   # a new measurement: its samples count from 0
            self.start_ns = status.start_ns
            self.next_index = [0, 0]
        periods = self.measure(handle, status.start_ns)
        counts, first_index = self.lib.global_fetch(handle)
        held_from = (max(0, first_index - 1), 0)   # index since start of the first sample held (blade, VR)
        samples: Samples = {}
        gaps: dict[str, int] = {}
        nxt = list(self.next_index)
        for i, name in enumerate(self.names):
            g = 0 if i < self.nblade else 1
            begin = max(self.next_index[g], held_from[g])
            values = self.lib.global_copy(handle, i, begin - held_from[g], held_from[g] + counts[g] - begin)
            origin = status.start_ns + (VR_OFFSET_NS if g else 0)
            samples[name] = (sample_end_times_ns(origin, periods[g], begin, len(values)), values)
            if begin > self.next_index[g]:
                gaps[name] = begin - self.next_index[g]
            finite = values[np.isfinite(values)]
            energy_j[name] = energy_j.get(name, 0.0) + float(finite.sum()) * periods[g] * 1e-9
            nxt[g] = begin + len(values)
        self.next_index = nxt
        return samples, gaps
