"""The demo numbers and report figures in docs/ come from `docs/make_docs.py` (issue 28: tui.md
quoted a datasheet IDD0 of 62.2 mA, "64.7 % → 0.4 %" and runs of 1.0/2.0/1.5 s from older code,
and docs/report's images were drawn by an older report)."""

from __future__ import annotations

import importlib.util
import json
import re
from pathlib import Path

DOCS = Path(__file__).resolve().parents[1] / "docs"


def _make_docs():
    spec = importlib.util.spec_from_file_location("make_docs", DOCS / "make_docs.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_facts_still_describe_this_code() -> None:
    """The stored facts name the demo's current datasheet, run lengths and thread rounds: change
    them in the code and this fails until `python3 docs/make_docs.py` is run again."""
    facts = json.loads((DOCS / "make_docs.json").read_text())
    assert facts["code"] == _make_docs().code_facts()


def test_every_generated_block_equals_its_rendering() -> None:
    """Every `<!-- make_docs:NAME -->` block of tui.md and report.md is what the script renders from
    the stored facts (an edit by hand, or new facts not rendered, fails)."""
    make_docs = _make_docs()
    facts = json.loads((DOCS / "make_docs.json").read_text())
    blocks = make_docs.render(facts)
    for doc in ("tui.md", "report.md"):
        text = (DOCS / doc).read_text()
        names = {m.group("name") for m in make_docs.BLOCK.finditer(text)}
        assert names, doc
        assert make_docs.rewrite(DOCS / doc, blocks) == text, doc
    assert facts["state"]["runs"] >= 10 and facts["headless"][0].startswith("state")


def test_the_screen_and_the_figures_belong_to_the_facts() -> None:
    """The drawn screen's datasheet IDD0 is the demo's; the seven report figures are there."""
    facts = json.loads((DOCS / "make_docs.json").read_text())
    screen = (DOCS / "tui.md").read_text().split("## The screen", 1)[1].split("```")[1]
    (idd0,) = re.findall(r"idd0 +([\d.]+)", screen)
    assert float(idd0) == facts["code"]["datasheet_ma"]["idd0"]
    figures = sorted(p.name for p in (DOCS / "report").glob("fig*.png"))
    assert figures == [f"fig{i}-{n}.png" for i, n in enumerate(
        ("energy", "currents", "residuals", "aging", "components", "jobs", "holdout"), start=1)]
