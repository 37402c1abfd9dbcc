"""``hdeem-watch demo --report DIR``: the report of the demo's state, written as the demo ends.

The demo's daemon is still running (its temporary state goes with it), so the state is read
read-only while it lives. A report that cannot be drawn costs one line, never the demo's exit.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TextIO


def report_at_end(state_dir: str | Path, out_dir: str | Path, *, stream: TextIO | None = None) -> bool:
    """Write the report of ``state_dir`` into ``out_dir``; print where it is (or why not).

    Returns:
        Whether the report was written.
    """
    from hdeem_watch.errors import InputError
    from hdeem_watch.report.style import MissingPlotting

    out = sys.stdout if stream is None else stream
    try:
        from hdeem_watch.report.build import write_report

        written = write_report(state_dir=str(state_dir), out=str(out_dir))
    except MissingPlotting:
        print("demo: no report: install hdeem-watch[report] (matplotlib) to draw reports", file=out, flush=True)
        return False
    except InputError as error:
        print(f"demo: no report: {error}", file=out, flush=True)
        return False
    print(f"demo: report written to {written.page} (open it in a browser)", file=out, flush=True)
    return True
