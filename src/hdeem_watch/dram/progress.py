"""How the DRAM model tells a caller how far a long step is: a callback, never output of its own.

Reading a multi-GB CPU trace, running the controller model over tens of millions of requests and
writing a DRAMPower trace take seconds to minutes. Each of these steps takes an optional
``progress`` callback and calls it now and then (once per chunk or batch, never per request) as
``progress(phase, done, total)``; the command line turns that into a bar on a terminal
(:mod:`hdeem_watch.cli.progress`), everything else passes nothing.

Example:
    >>> seen = []
    >>> report: ProgressCallback = lambda phase, done, total: seen.append((phase, done, total))
    >>> report("controller model", 131072, 262144)
    >>> seen
    [('controller model', 131072, 262144)]
"""

from __future__ import annotations

from collections.abc import Callable

#: ``progress(phase, done, total)``: ``done`` of ``total`` units (bytes, requests, lines) of the
#: step named ``phase`` are finished.
ProgressCallback = Callable[[str, int, int], None]
