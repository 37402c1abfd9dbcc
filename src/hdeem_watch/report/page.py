"""The report page: one self-contained HTML file (figures as ``data:`` SVG images, styles inline, no
script, nothing fetched from the network), with every figure's numbers and the calibrated memspec.

Example:
    >>> html = render_page("t", "source", [], {}, None, notes=("a note",), generated="now")
    >>> "<h1>t</h1>" in html and "a note" in html
    True
"""

from __future__ import annotations

import base64
import html as _html
import json
from collections.abc import Mapping, Sequence
from typing import Any

from hdeem_watch.report.figure import Table, fmt

_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",sans-serif;max-width:1100px;margin:1.5em auto;padding:0 1em;
color:#111;background:#fff;line-height:1.4}
h1{font-size:1.5em}h2{font-size:1.2em;margin-top:2em;border-bottom:1px solid #ccc}h3{font-size:1em}
figure{margin:0}figure img{max-width:100%;height:auto;border:1px solid #ddd}
.how{color:#333;font-style:italic}.missing{background:#fff4e0;border-left:4px solid #E69F00;padding:.3em .6em}.note{border-left:4px solid #0072B2;padding:.3em .6em}
table{border-collapse:collapse;font-size:.85em;margin:.5em 0 1em}th,td{border:1px solid #ccc;padding:2px 6px;
text-align:right}th{background:#f2f2f2}td:first-child,th:first-child{text-align:left}
pre{background:#f6f6f6;padding:.6em;overflow:auto;font-size:.8em;max-height:30em}.notes li{margin:.2em 0}
"""


def svg_data_uri(svg: bytes) -> str:
    """An SVG document as a ``data:`` URI (base64), usable as an ``<img>`` source."""
    return "data:image/svg+xml;base64," + base64.b64encode(svg).decode("ascii")


def table_html(table: Table) -> str:
    """A :class:`Table` as an HTML table (unknown cells as "–")."""
    head = "".join(f"<th>{_html.escape(c)}</th>" for c in table.columns)
    body = "".join("<tr>" + "".join(f"<td>{_html.escape(fmt(v))}</td>" for v in row) + "</tr>" for row in table.rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def render_page(title: str, source: str, figures: Sequence[Mapping[str, Any]],
                tables: Mapping[str, Mapping[str, Table]], memspec: Mapping[str, Any] | None, *,
                notes: Sequence[str] = (), generated: str = "") -> str:
    """The whole page.

    Args:
        title: the page title.
        source: what the report was drawn from.
        figures: per figure ``{"key", "title", "how_to_read", "svg" (bytes), "missing" (sequence), "notes" (sequence)}``.
        tables: per figure title, its tables by caption (section 7).
        memspec: the calibrated memspec (DRAMPower JSON), None if there is none.
        notes: sentences about what the input lacks.
        generated: when the report was drawn (shown as is).
    """
    esc = _html.escape
    parts = [
        "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        '<link rel="icon" href="data:,">', f"<title>{esc(title)}</title><style>{_CSS}</style></head><body>",
        f"<h1>{esc(title)}</h1>", f"<p>From {esc(source)}. Drawn {esc(generated)}.</p>",
    ]
    if notes:
        parts.append('<ul class="notes">' + "".join(f"<li>{esc(n)}</li>" for n in notes) + "</ul>")
    for number, figure in enumerate(figures, start=1):
        parts.append(f'<section id="{esc(figure["key"])}"><h2>{number}. {esc(figure["title"])}</h2>')
        parts.append(f'<p class="how">{esc(figure["how_to_read"])}</p>')
        for missing in figure.get("missing", ()):
            parts.append(f'<p class="missing">No data: {esc(missing)}.</p>')
        for note in figure.get("notes", ()):
            parts.append(f'<p class="note">Note: {esc(note)}.</p>')
        parts.append(f'<figure><img src="{svg_data_uri(figure["svg"])}" alt="{esc(figure["title"])}"></figure>')
        parts.append("</section>")
    parts.append(f'<section id="numbers"><h2>{len(figures) + 1}. The numbers of every figure, and the '
                 "calibrated memspec</h2>")
    for figure_title, captioned in tables.items():
        parts.append(f"<h3>{esc(figure_title)}</h3>")
        if not captioned:
            parts.append("<p>No numbers (no data).</p>")
        for caption, table in captioned.items():
            parts.append(f"<p>{esc(caption)}</p>{table_html(table)}")
    parts.append("<h3>Calibrated memspec (DRAMPower JSON)</h3>")
    if memspec is None:
        parts.append('<p class="missing">No data: no calibration (or no memspec) to write.</p>')
    else:
        parts.append(f"<pre>{esc(json.dumps(memspec, indent=2))}</pre>")
    parts.append("</section></body></html>")
    return "\n".join(parts) + "\n"
