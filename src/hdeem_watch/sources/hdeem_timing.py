"""Sample times of HDEEM's global readings, from the measurement's own start time and counts.

The global buffer has no per-sample time stamps. Score-P's HDEEM plugin
(``score-p/scorep_plugin_hdeem``, ``hdeem_plugin.cpp``) rebuilds them from ``hdeem_status_t``'s
``start_time_blade`` and the sample counts: the period is the measured duration ÷ the number of
samples (not the nominal 1 ms / 10 ms), and VR samples are shifted by ``-(35000 - 5600)`` µs. The
Taurus captures show why: 1003.07 / 98.66 Sa/s measured over 60 ms, 1000.0008 / 100.063 Sa/s over
1.6 s (``6415.txt``, ``6485taurus.txt``), and VR statistics times ~30 ms before the blade's. At the
nominal rates a 100 Sa/s reconstruction is a whole sample off after ~70 samples at 98.66 Sa/s.

Here the duration ends at the statistics' read time of each group (``hdeem_get_stats``: the end of
the last sample counted), which is exact at any moment of a running measurement, where Score-P's
``stop_time_blade`` exists only after the stop.

Example:
    >>> blade, vr = measured_periods_ns(0, (1000, 100), (1_000_000_000, 1_000_000_000 + VR_OFFSET_NS))
    >>> blade, vr
    (1000000.0, 10000000.0)
    >>> sample_end_times_ns(5_000, 1000.0, 0, 3).tolist()
    [6000, 7000, 8000]
"""

from __future__ import annotations

import numpy as np

#: VR samples are taken this long before their place on the blade clock (Score-P's ``time_offset_vr``).
VR_OFFSET_NS = -(35_000 - 5_600) * 1_000
#: Nominal sampling periods (ns): BLADE 1000 Sa/s, VR 100 Sa/s.
NOMINAL_PERIOD_NS = (1_000_000.0, 10_000_000.0)
#: Fewer samples than this give no trustworthy measured period: the nominal one is used.
MIN_SAMPLES = 2


def measured_periods_ns(start_ns: int, counts: tuple[int, int], read_ns: tuple[int, int]) -> tuple[float, float]:
    """Blade and VR sampling periods (ns) measured as duration ÷ count since the measurement's start.

    Args:
        start_ns: ``start_time_blade`` (wall ns).
        counts: samples since start (blade, VR), from ``hdeem_get_stats``.
        read_ns: read times (blade, VR) of those statistics: the end of the last sample counted.

    Returns:
        The periods; a group with fewer than :data:`MIN_SAMPLES` samples or no positive duration
        keeps its nominal period.
    """
    periods = []
    for group, origin in enumerate((start_ns, start_ns + VR_OFFSET_NS)):
        n, duration = counts[group], read_ns[group] - origin
        periods.append(duration / n if n >= MIN_SAMPLES and duration > 0 else NOMINAL_PERIOD_NS[group])
    return periods[0], periods[1]


def sample_end_times_ns(origin_ns: int, period_ns: float, first: int, count: int) -> np.ndarray:
    """End times (int64 ns) of samples ``first .. first+count-1`` (0-based since the start) of a grid
    that begins at ``origin_ns`` (``start_time_blade``, plus :data:`VR_OFFSET_NS` for VR)."""
    index = np.arange(first + 1, first + count + 1, dtype=np.float64)
    return np.int64(origin_ns) + np.rint(index * period_ns).astype(np.int64)
