"""The source factory: builds a source by kind and says, for every kind, whether it can be used here.

It sits above every source module and none of them imports it, so the sources stay free of import
circles (``base`` holds only the contract they share). Each source is imported when it is asked
for: building the sim does not load the HDEEM or RAPL code.

Example:
    >>> from hdeem_watch.channels import CHANNELS
    >>> src = make_source("sim", seed=1)
    >>> src.open()
    >>> batch = src.poll()
    >>> sorted(batch.samples) == sorted(CHANNELS)
    True
    >>> src.close()
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hdeem_watch.errors import InputError
from hdeem_watch.sources.base import HasLayout, Source

#: Source kinds :func:`make_source` knows.
SOURCE_KINDS = ("sim", "hdeem", "rapl", "replay")


def make_source(kind: str, **options: Any) -> Source:
    """Build a source by kind.

    Args:
        kind: ``"sim"``, ``"hdeem"``, ``"rapl"`` or ``"replay"``.
        **options: passed to the source's constructor (e.g. ``seed``, ``clock``, ``speed`` for the
            sim; ``root`` for RAPL; ``path``, ``speed``, ``loop`` for replay; ``include_dir``,
            ``lib_dir``, ``host`` for HDEEM).

    Raises:
        SourceUnavailable: the source cannot be used here (reason says why and the fix).
        InputError: ``kind`` is not a known kind, or an option is bad (e.g. a malformed recording).
    """
    if kind == "sim":
        from hdeem_watch.sources.sim import SimSource

        return SimSource(**options)
    if kind == "hdeem":
        from hdeem_watch.sources.hdeem import HdeemSource

        return HdeemSource(**options)
    if kind == "rapl":
        from hdeem_watch.sources.rapl import RaplSource

        return RaplSource(**options)
    if kind == "replay":
        from hdeem_watch.sources.replay import ReplaySource

        return ReplaySource(**options)
    raise InputError(f"source: unknown kind {kind!r}; expected one of {', '.join(SOURCE_KINDS)}")


def simulated_memspec(source: Source) -> str | None:
    """The memspec the hidden truth of a simulated node is built on: a preset name (the Haswell
    node's DDR4 DIMMs) or the path of the sim's memspec file (the DDR5 node's sub-channel,
    ``sim/ddr5_node.json``); None: ``source`` measures a real node, whose DIMMs choose its memspec."""
    if source.kind != "sim":
        return None
    from hdeem_watch.sim.layout import SimLayout
    from hdeem_watch.sim.model import memspec_setting

    layout = source.layout if isinstance(source, HasLayout) else None
    return memspec_setting(layout) if isinstance(layout, SimLayout) else memspec_setting()


def available_sources(**options: Any) -> dict[str, str | None]:
    """For each kind, ``None`` if it can be used here, else the reason why not (with the fix).

    Options are passed to the probes (``rapl_root=...``, ``hdeem_include_dir=...``,
    ``hdeem_lib_dir=...``, ``replay_path=...``).
    """
    from hdeem_watch.sources.hdeem import probe as hdeem_probe
    from hdeem_watch.sources.rapl import probe as rapl_probe

    path = options.get("replay_path")
    return {
        "sim": None,
        "hdeem": hdeem_probe(include_dir=options.get("hdeem_include_dir"), lib_dir=options.get("hdeem_lib_dir")),
        "rapl": rapl_probe(root=options.get("rapl_root")),
        # available without a path (it needs path=RECORDING.csv to be built)
        "replay": None if path is None or Path(path).is_file() else f"replay: {path}: no such file",
    }
