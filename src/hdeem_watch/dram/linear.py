"""The linear energy of command statistics under the energy model of the memspec's standard.

One entry point for code that takes a DDR4 :class:`~hdeem_watch.dram.memspec.MemSpec` or a DDR5
:class:`~hdeem_watch.dram.memspec_ddr5.MemSpecDDR5` alike (the calibration's rows, the simulated
node's truth): :func:`linear_energy` dispatches on the memspec's type to
:func:`hdeem_watch.dram.energy.energy_columns` (columns over ``CURRENT_NAMES``) or
:func:`hdeem_watch.dram.energy_ddr5.energy_columns_ddr5` (over ``CURRENT_NAMES_DDR5``);
:func:`model_current_names` gives the column order.

Example:
    >>> from hdeem_watch.dram.memspec import preset
    >>> model_current_names(preset("ddr4-2133-x8-4gb"))[:3]
    ('idd0', 'idd2n', 'idd3n')
"""

from __future__ import annotations

from hdeem_watch.dram.energy import CURRENT_NAMES, LinearEnergy, energy_columns
from hdeem_watch.dram.energy_ddr5 import CURRENT_NAMES_DDR5, energy_columns_ddr5
from hdeem_watch.dram.memspec import MemSpec
from hdeem_watch.dram.memspec_ddr5 import MemSpecDDR5
from hdeem_watch.dram.stats import CommandStats


def linear_energy(spec: MemSpec | MemSpecDDR5, stats: CommandStats) -> LinearEnergy:
    """Joules per ampere of every current of ``spec``'s standard (and the constant) for ``stats``."""
    if isinstance(spec, MemSpecDDR5):
        return energy_columns_ddr5(spec, stats)
    return energy_columns(spec, stats)


def model_current_names(spec: object) -> tuple[str, ...]:
    """The column order of :func:`linear_energy` for ``spec`` (DDR4's for anything not DDR5)."""
    return tuple(CURRENT_NAMES_DDR5) if isinstance(spec, MemSpecDDR5) else tuple(CURRENT_NAMES)
