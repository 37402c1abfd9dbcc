"""The source contract: names, factory, availability report, protocol conformance."""

from __future__ import annotations

import pytest

from hdeem_watch.errors import InputError
from hdeem_watch.sources.base import (
    CHANNELS,
    DRAM_CHANNELS,
    RAPL_DRAM_COVERS,
    Source,
    hdeem_channel_infos,
    normalise_channel_name,
)
from hdeem_watch.sources.hdeem import HdeemSource
from hdeem_watch.sources.rapl import RaplSource
from hdeem_watch.sources.registry import available_sources, make_source
from hdeem_watch.sources.replay import ReplaySource, write_recording


@pytest.mark.parametrize(("raw", "canonical"), [
    ("ddr ab", "DDR_AB"), ("Ddr_Ab", "DDR_AB"), ("DDRAB", "DDR_AB"), (" blade ", "BLADE"),
    ("cpu 1", "CPU1"), ("DDR-GH", "DDR_GH"), ("fan speed", "FAN_SPEED"),
])
def test_channel_names_are_normalised(raw, canonical):
    """Case, spaces, '-' and '_' variants map onto CHANNELS; unknown names are upper-cased with '_'."""
    assert normalise_channel_name(raw) == canonical


def test_hdeem_channel_set():
    """HDEEM: BLADE at 1000 Sa/s, the other six at 100 Sa/s; the pairs are the DRAM channels."""
    infos = hdeem_channel_infos()
    assert [i.name for i in infos] == list(CHANNELS)
    assert {i.name for i in infos if i.kind == "dram"} == set(DRAM_CHANNELS)
    assert [i.rate_hz for i in infos] == [1000.0] + [100.0] * 6
    assert sorted(sum(RAPL_DRAM_COVERS.values(), ())) == sorted(DRAM_CHANNELS)


def test_factory_and_unknown_kind(tmp_path):
    """make_source builds each kind; an unknown kind is an InputError listing the kinds."""
    path = tmp_path / "r.csv"
    write_recording(path, {"BLADE": ([1, 2], [1.0, 2.0])})
    assert isinstance(make_source("replay", path=path), ReplaySource)
    assert isinstance(make_source("rapl", root=tmp_path), RaplSource)
    assert isinstance(make_source("hdeem"), HdeemSource)
    with pytest.raises(InputError, match="sim, hdeem, rapl, replay"):
        make_source("ipmi")


def test_every_source_satisfies_the_protocol(tmp_path):
    """Sim, HDEEM, RAPL and replay objects all satisfy the Source protocol."""
    path = tmp_path / "r.csv"
    write_recording(path, {"BLADE": ([1, 2], [1.0, 2.0])})
    for src in (make_source("sim"), HdeemSource(), RaplSource(root=tmp_path), ReplaySource(path)):
        assert isinstance(src, Source), type(src)


def test_available_sources_reports_reasons(tmp_path):
    """The sim is always available; the others say why not (missing header, no powercap, no file)."""
    report = available_sources(hdeem_include_dir=str(tmp_path), rapl_root=str(tmp_path / "none"),
                               replay_path=str(tmp_path / "missing.csv"))
    assert report["sim"] is None
    assert "hdeem.h" in report["hdeem"]
    assert "does not exist" in report["rapl"]
    assert "no such file" in report["replay"]
