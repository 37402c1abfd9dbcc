"""The sim's truth in the calibration views: the effective truth (incl. I/O) compared with the fit, core kept."""

from __future__ import annotations

import math

from hdeem_watch.tui.headless import calib_line
from hdeem_watch.tui.records import SimCurrentView, calib_view
from hdeem_watch.tui.widgets.calib import calib_text

FIT = {
    "currents": {
        "idd4r": {"datasheet": 0.0972, "calibrated": 0.0661, "ci95": [0.065, 0.067], "identifiable": True},
        "idd2n": {"datasheet": 0.0578, "calibrated": 0.0450, "ci95": [0.0449, 0.0451], "identifiable": True},
    },
    "error": {"before": 0.44, "after": 0.002, "loo": 0.003},
    "n_runs": 27,
}
TRUTH = {
    "simulated": True,
    "mean_currents_a": {"idd4r": 0.0556, "idd2n": 0.0468},
    "effective_currents_a": {"idd4r": 0.0661, "idd2n": 0.0450},
}


def test_effective_truth_is_compared_and_core_truth_kept() -> None:
    """With ``effective_currents_a`` the view's truth is the effective one and the core truth rides along."""
    view = calib_view({"fit": FIT, "truth": TRUTH, "suggest": [["copy-1t", 0.4]]})
    idd4r = next(c for c in view.currents if c.name == "idd4r")
    assert idd4r.truth_a == 0.0661
    assert isinstance(idd4r, SimCurrentView) and idd4r.truth_core_a == 0.0556
    assert view.suggested_next == "copy-1t"
    old = calib_view({"fit": FIT, "truth": {"simulated": True, "mean_currents_a": TRUTH["mean_currents_a"]}})
    assert next(c for c in old.currents if c.name == "idd4r").truth_a == 0.0556
    assert math.isnan(getattr(old.currents[0], "truth_core_a", math.nan))


def test_panel_and_headless_label_the_effective_truth() -> None:
    """The panel says "incl. I/O" and shows a core column when wide enough; the headless line names both."""
    view = calib_view({"fit": FIT, "truth": TRUTH, "suggest": [["copy-1t", 0.4]]})
    wide = calib_text(view, 80).plain
    assert "incl. I/O" in wide and "core" in wide and "55.6" in wide and "66.1" in wide
    assert "suggested run: copy-1t" in wide
    narrow = calib_text(view, 40).plain
    assert "core" not in narrow and "66.1" in narrow
    line = calib_line(view)
    assert "idd4r 97.2->66.1 mA (sim incl. I/O 66.1, core 55.6)" in line
    assert "?" not in line
