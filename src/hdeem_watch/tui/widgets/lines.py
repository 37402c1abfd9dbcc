"""A widget that shows prepared lines: the cheapest way to repaint text at a fixed rate.

The panels build Rich :class:`~rich.text.Text` (or plain ``(text, style)`` runs) from a snapshot;
:class:`LinesWidget` turns each line into a Textual :class:`~textual.strip.Strip` once and
serves them from ``render_line`` — no markup parsing, no wrapping, no layout work per frame.
Lines are cropped to the widget's width; missing lines are blank; when the screen has the
``-stale`` class (the node went silent) every line is dimmed.
"""

from __future__ import annotations

from functools import lru_cache

from rich.segment import Segment
from rich.style import Style
from rich.text import Text
from textual.strip import Strip
from textual.widget import Widget

Run = tuple[str, str]
_DIM = Style(dim=True)


@lru_cache(maxsize=256)
def style_of(spec: str) -> Style:
    """A parsed Rich style (cached: the panels use a handful)."""
    return Style.parse(spec) if spec else Style()


class LinesWidget(Widget):
    """Shows a list of prepared lines; :attr:`plain` gives their text (for tests)."""

    DEFAULT_CSS = "LinesWidget { height: auto; }"

    def __init__(self, *, id: str | None = None, classes: str | None = None) -> None:
        super().__init__(id=id, classes=classes)
        self._strips: list[Strip] = []
        self._last: object = None
        self._rendered: dict[tuple[int, int], Strip] = {}
        self._base = Style()
        self._source: object = None
        self._source_size: object = None
        self.plain = ""

    def already_showing(self, source: object) -> bool:
        """Whether ``source`` (a snapshot or a part of one) is what this widget last painted, at
        this size; if not, remember it as painted now.

        The widget keeps a reference to ``source`` and compares by identity: an ``id()`` alone is
        reused by CPython as soon as the old snapshot is freed, and a new snapshot would be skipped.
        """
        if source is self._source and self.size == self._source_size:
            return True
        self._source = source
        self._source_size = self.size
        return False

    def set_text(self, text: Text) -> None:
        """Show ``text`` (one Strip per line); nothing happens when it did not change."""
        if text == self._last:
            return
        self._last = text
        console = self.app.console
        lines = text.split("\n", allow_blank=True)
        self._set_strips([Strip(list(line.render(console))) for line in lines], text.plain)

    def set_runs(self, lines: list[list[Run]]) -> None:
        """Show lines given as ``(text, style)`` runs (the fast path of the plots)."""
        if lines == self._last:
            return
        self._last = lines
        strips = [Strip([Segment(t, style_of(s)) for t, s in line]) for line in lines]
        self._set_strips(strips, "\n".join("".join(t for t, _ in line) for line in lines))

    def _set_strips(self, strips: list[Strip], plain: str) -> None:
        relayout = len(strips) != len(self._strips)
        self._strips = strips
        self.plain = plain
        self._rendered.clear()
        self.refresh(layout=relayout)

    def restyle(self) -> None:
        """Forget the finished lines (the base style changed, e.g. the screen went stale)."""
        self._rendered.clear()
        self.refresh()

    def get_content_height(self, container, viewport, width: int) -> int:  # type: ignore[no-untyped-def]
        return len(self._strips)

    def render_line(self, y: int) -> Strip:
        width = self.size.width
        key = (y, width)
        done = self._rendered.get(key)
        if done is not None:
            return done
        if not self._rendered:  # the base style is looked up once per change, not per line
            self._base = self.rich_style + _DIM if self.screen.has_class("-stale") else self.rich_style
        base = self._base
        if 0 <= y < len(self._strips):
            done = self._strips[y].crop(0, width).apply_style(base).extend_cell_length(width, base)
        else:
            done = Strip.blank(width, base)
        self._rendered[key] = done
        return done
