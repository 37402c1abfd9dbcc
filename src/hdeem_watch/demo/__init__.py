"""The embedded demo and the fake node: everything that stands in for a real cluster node.

:mod:`~hdeem_watch.demo.daemon` starts a sim-source ``hdeem-watch daemon`` subprocess on private
ipc endpoints, :mod:`~hdeem_watch.demo.schedule` announces benchmark runs to it, and
:mod:`~hdeem_watch.demo.fakenode` is a cheap wire-protocol publisher for UI tests and benchmarks.
The TUI does not depend on this package; ``hdeem-watch demo`` (``cli/demo.py``) puts them together.
See docs/tui.md.
"""
