"""For every preset and every kernel, every energy component of the model is >= 0 (issue 15)."""

from __future__ import annotations

import pytest

from hdeem_watch.dram.energy import COMPONENTS, core_energy
from hdeem_watch.dram.kernels import KERNELS, kernel_stats
from hdeem_watch.dram.memspec import preset
from hdeem_watch.dram.presets import PRESETS


@pytest.mark.parametrize("name", sorted(PRESETS))
@pytest.mark.parametrize("threads", [1, 12])
def test_every_component_non_negative(name: str, threads: int) -> None:
    """``model kernel``'s energy: no component of any kernel is negative with any preset."""
    spec = preset(name)
    for kernel in KERNELS:
        model = kernel_stats(spec, kernel, 1 << 18, threads, channels=4)
        energy = core_energy(spec, model.stats)
        for component in COMPONENTS:
            assert energy.components[component] >= 0.0, (name, kernel, component, energy.components)
        assert energy.components["act_j"] > 0.0 and energy.components["rd_j"] > 0.0, (name, kernel)


def test_old_samsung_division_was_negative() -> None:
    """The bug this guards: module IDDs / 18 gave a negative activation energy for ``read``."""
    spec = preset("samsung-m393a1g43db0-cpb")
    old = spec.with_currents({n: v / 18 for n, v in {"idd0": 1.120, "idd2n": 1.040, "idd3n": 1.540,
                                                      "idd4r": 1.750, "idd4w": 1.590}.items()})
    model = kernel_stats(old, "read", 1 << 18, 1, channels=4)
    assert core_energy(old, model.stats).components["act_j"] < 0.0
    assert core_energy(spec, model.stats).components["act_j"] > 0.0
