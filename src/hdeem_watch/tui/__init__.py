"""The live terminal UI of hdeem-watch and the embedded demo.

Background feeds (:mod:`~hdeem_watch.tui.feed`) read the daemons' wire protocol and build
immutable snapshots (:mod:`~hdeem_watch.tui.snapshot`) with the pure node model
(:mod:`~hdeem_watch.tui.model`); the Textual app (:mod:`~hdeem_watch.tui.app`) paints the newest
at a fixed rate. See docs/tui.md.
"""
