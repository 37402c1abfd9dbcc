"""The report page in a real browser: Debian's Chromium, started by the test (headless), opens the
page from the file system with no network, shows no console problem, and draws every figure."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hdeem_watch.report.build import build_report
from hdeem_watch.report.state_reader import read_state

from .chromium import CHROMIUM, Chromium

IMAGE_RECTS = ("Array.from(document.images).map(i => { const r = i.getBoundingClientRect(); "
               "return [r.left + scrollX, r.top + scrollY, r.width, r.height, i.complete && i.naturalWidth > 0]; })")


def _region_stats(pixels: np.ndarray, rect: list[float]) -> tuple[float, float]:
    """(standard deviation, fraction of non-white pixels) of a screenshot region (RGB in 0..1)."""
    left, top, width, height = (round(v) for v in rect[:4])
    region = pixels[top:top + height, left:left + width, :3]
    assert region.size > 0
    return float(region.std()), float((region.min(axis=2) < 0.9).mean())


@pytest.fixture
def browser(tmp_path: Path) -> Chromium:
    assert CHROMIUM.exists(), "the browser test needs Debian's chromium (apt-get install chromium)"
    with Chromium(tmp_path / "profile") as chromium:
        yield chromium


#: Height (CSS px) below which an embedded figure is a one-panel message ("no job records"), not a plot.
MESSAGE_HEIGHT = 250


@pytest.mark.slow
@pytest.mark.parametrize("source", ["aged-state", "examples-runs"])
def test_page_opens_without_console_problems_and_every_figure_is_drawn(
        source: str, aged_state_dir: Path, tmp_path: Path, browser: Chromium) -> None:
    """Seven figures are loaded and laid out; each region of the full-page screenshot holds a drawing
    (varied pixels, a real share of them not white) or is one short message panel; the console
    stays empty. Issue 28: for a daemon state with per-pair fits and an alarm, and for
    examples/RUNS.json (one fit, no baselines, no jobs: before, one-point axes and empty boxes).
    The screenshot stays in the test's temporary directory (report-<source>.png) to look at."""
    import matplotlib.image

    from hdeem_watch.report.runs_reader import read_runs

    examples = Path(__file__).resolve().parents[2] / "examples" / "RUNS.json"
    data = read_state(aged_state_dir) if source == "aged-state" else read_runs(examples)
    written = build_report(data, tmp_path / "report", fmt="html")
    browser.open(written.page.resolve().as_uri())
    assert browser.console_problems() == []
    rects = browser.evaluate(IMAGE_RECTS)
    assert len(rects) == 7
    assert all(r[4] for r in rects), "an embedded figure failed to decode"
    assert all(r[2] >= 600 and r[3] >= 120 for r in rects), rects
    shot = tmp_path / f"report-{source}.png"
    browser.screenshot(shot)
    pixels = matplotlib.image.imread(shot)
    assert pixels.shape[0] >= max(r[1] + r[3] for r in rects) - 1
    for rect in rects:
        spread, inked = _region_stats(pixels, rect)
        assert spread > 0.05 and inked > 0.005, (rect, spread, inked)
    plots = [r for r in rects if r[3] >= MESSAGE_HEIGHT]
    messages = [r for r in rects if r[3] < MESSAGE_HEIGHT]
    # the state has every figure but jobs and hold-out runs (it predates them); the RUNS.json lacks
    # time series (aging), jobs and hold-out runs
    assert (len(plots), len(messages)) == ((5, 2) if source == "aged-state" else (4, 3)), rects
    assert browser.evaluate("document.querySelectorAll('table').length") >= 6


@pytest.mark.slow
def test_the_checks_catch_a_broken_page(tmp_path: Path, browser: Chromium) -> None:
    """Control: a console error, an uncaught exception and an image that does not load are all
    reported, and the broken image's region is blank."""
    import matplotlib.image

    page = tmp_path / "broken.html"
    page.write_text('<!DOCTYPE html><html><head><link rel="icon" href="data:,"></head><body>'
                    '<img src="missing.png" width="640" height="300" style="display:block">'
                    '<script>console.error("figure failed"); null.x;</script></body></html>')
    browser.open(page.as_uri())
    problems = browser.console_problems()
    assert any("figure failed" in p for p in problems)
    assert any("Uncaught" in p for p in problems)
    assert any("Failed to load resource" in p for p in problems)
    (rect,) = browser.evaluate(IMAGE_RECTS)
    assert rect[4] is False
    shot = tmp_path / "broken.png"
    browser.screenshot(shot)
    spread, inked = _region_stats(matplotlib.image.imread(shot), rect)
    assert inked < 0.01 or spread < 0.08
