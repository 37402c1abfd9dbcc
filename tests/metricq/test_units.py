"""The pure parts of the MetricQ source: names, translation, outbox, settings, backoff."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hdeem_watch.cli import main
from hdeem_watch.errors import InputError
from hdeem_watch.metricq.naming import MetricNames, check_prefix
from hdeem_watch.metricq.outbox import Outbox
from hdeem_watch.metricq.settings import load_source_settings, read_secret_file
from hdeem_watch.metricq.translate import Points, StreamTranslator
from hdeem_watch.wire import protocol


def samples(node: str, channel: str, t: list[int], p: list[float], rate: float = 100.0, seq: int = 0) -> protocol.Message:
    frames = protocol.encode_samples(node, channel, seq=seq, rate_hz=rate, t_wall_ns=np.array(t, dtype=np.int64),
                                     power_w=np.array(p), energy_j=0.0, status="ok")
    return protocol.decode(frames)


def body(node: str, kind: str, header: dict, t_ns: int = 5_000, seq: int = 0) -> protocol.Message:
    return protocol.decode(protocol.encode(protocol.topic(node, kind),
                                           {"v": 1, "seq": seq, "node": node, "t_ns": t_ns, **header}))


def test_power_metric_name_and_metadata_per_channel() -> None:
    tr = StreamTranslator(MetricNames("site.hw"))
    out = tr.translate(samples("n7", "BLADE", [1, 2, 3], [70.0, 71.0, 72.0], rate=1000.0))
    assert list(out.declarations) == ["site.hw.n7.blade.power"]
    meta = out.declarations["site.hw.n7.blade.power"]
    assert (meta["unit"], meta["rate"], meta["scope"], meta["quantity"]) == ("W", 1000.0, "last", "power")
    assert out.points[0].values.tolist() == [70.0, 71.0, 72.0]
    assert tr.translate(samples("n7", "BLADE", [4], [1.0], rate=1000.0)).declarations == {}


def test_above_baseline_is_nan_until_a_baseline_then_the_difference() -> None:
    tr = StreamTranslator(MetricNames("s"), ["above_baseline"])
    first = tr.translate(samples("n1", "DDR_CD", [10, 20], [3.0, 4.0]))
    assert [p.metric for p in first.points] == ["s.n1.dram.cd.above_baseline.power"]
    assert np.isnan(first.points[0].values).all()
    tr.translate(body("n1", "baseline", {"channels": {"DDR_CD": {"power_w": 1.25, "spread_w": 0.1, "n": 5,
                                                                 "t_ns": 1, "origin": "quiet"}}}))
    second = tr.translate(samples("n1", "DDR_CD", [30, 40], [3.0, 4.5]))
    assert second.points[0].values.tolist() == [1.75, 3.25]
    assert tr.translate(samples("n1", "BLADE", [50], [9.0])).points == []  # not a DIMM pair


def test_calibrated_currents_are_slow_metrics_from_the_fit() -> None:
    tr = StreamTranslator(MetricNames("s"))
    assert tr.translate(body("n1", "calib", {"fit": None, "memspec": "x"})).points == []
    fit = {"currents": {"idd0": {"calibrated": 0.061}, "idd4r": {"calibrated": None}}}
    out = tr.translate(body("n1", "calib", {"fit": fit, "memspec": "ddr4"}, t_ns=7_000))
    values = {p.metric: (p.t_ns.tolist(), p.values.tolist()) for p in out.points}
    assert values["s.n1.dram.calibrated.idd0.current"] == ([7_000], [0.061])
    assert math.isnan(values["s.n1.dram.calibrated.idd4r.current"][1][0])  # unknown stays NaN, never 0
    meta = out.declarations["s.n1.dram.calibrated.idd0.current"]
    assert (meta["unit"], meta["scope"]) == ("A", "next") and "ddr4" in meta["description"]
    again = tr.translate(body("n1", "calib", {"fit": fit, "memspec": "ddr4"}, t_ns=7_000))
    assert again.points == [] and tr.out_of_order == 2  # a re-publication at the same time is not sent twice


def test_times_going_back_after_a_daemon_restart_are_left_out() -> None:
    tr = StreamTranslator(MetricNames("s"), ["power"])
    tr.translate(samples("n1", "CPU0", [100, 200], [1.0, 2.0]))
    out = tr.translate(samples("n1", "CPU0", [150, 250, 300], [5.0, 6.0, 7.0]))
    assert out.points[0].t_ns.tolist() == [250, 300] and tr.out_of_order == 1


def test_node_names_and_prefixes() -> None:
    assert MetricNames("a").power("Node-7.cluster", "DDR_GH") == "a.node-7_cluster.dram.gh.power"
    for bad in ("", "Upper", "a..b", ".a", "a b"):
        with pytest.raises(InputError, match="prefix"):
            check_prefix(bad)


def test_outbox_drops_oldest_beyond_capacity_and_requeues_in_front() -> None:
    box = Outbox(capacity=4)
    box.push([Points("a", np.arange(3), np.zeros(3)), Points("b", np.arange(3), np.ones(3))])
    assert len(box) == 4 and box.dropped == 2
    taken = box.take()
    assert [p.metric for p in taken] == ["a", "b"] and len(box) == 0
    box.push([Points("c", np.arange(1), np.zeros(1))])
    box.requeue(taken)  # 5 values for 4 places: the oldest (a's) goes
    assert [p.metric for p in box.take()] == ["b", "c"] and box.dropped == 3
    box.push([Points("d", np.arange(1), np.zeros(1))])
    box.requeue([Points("a", np.arange(2), np.zeros(2))])
    assert [p.metric for p in box.take()] == ["a", "d"]


def test_settings_precedence_file_env_flags(tmp_path: Path) -> None:
    config = tmp_path / "hw.toml"
    config.write_text('[daemon]\nnode = "n1"\n[metricq]\nserver = "amqp://file/"\nprefix = "site"\n'
                      'metrics = ["power"]\n')
    s = load_source_settings(config, env={"HDEEM_WATCH_METRICQ_PREFIX": "env.site"}, overrides={"token": "t1"})
    assert (s.server, s.prefix, s.metrics, s.token) == ("amqp://file/", "env.site", ("power",), "t1")
    s = load_source_settings(config, env={}, overrides={"prefix": "flag"})
    assert s.prefix == "flag"
    config.write_text('[metricq]\nserver = "amqp://x/"\nbogus = 1\n')
    with pytest.raises(InputError, match=r"hw.toml \[metricq\]: unknown setting 'bogus'"):
        load_source_settings(config, env={})
    with pytest.raises(InputError, match="metrics"):
        load_source_settings(None, env={}, overrides={"server": "amqp://x/", "metrics": "power,watts"})
    with pytest.raises(InputError, match="amqp"):
        load_source_settings(None, env={}, overrides={"server": "http://x/"})


def test_credentials_files_must_be_private(tmp_path: Path) -> None:
    secret = tmp_path / "url"
    secret.write_text("amqp://hw:pw@rabbit/\n")
    secret.chmod(0o640)
    with pytest.raises(InputError, match="mode 0640 lets group or others read it"):
        read_secret_file(secret)
    secret.chmod(0o600)
    s = load_source_settings(None, env={}, overrides={"server_file": str(secret)})
    assert s.server == "amqp://hw:pw@rabbit/"
    token = tmp_path / "token"
    token.write_text("source-x\n")
    token.chmod(0o604)
    with pytest.raises(InputError, match="token"):
        load_source_settings(None, env={}, overrides={"server": "amqp://x/", "token_file": str(token)})


def test_cli_bad_input_is_one_line_and_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    token = tmp_path / "token"
    token.write_text("t\n")
    token.chmod(0o644)
    code = main(["metricq-source", "--server", "amqp://localhost/", "--token-file", str(token)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "chmod 600" in err
    assert main(["metricq-source", "--server", "amqp://localhost/", "--duration", "0"]) == 2


def test_default_token_names_the_host_and_a_token_file_is_read(tmp_path: Path) -> None:
    import socket

    s = load_source_settings(None, env={}, overrides={"server": "amqp://x/"})
    assert s.token == f"source-hdeem-watch-{socket.gethostname().split('.')[0]}"
    token = tmp_path / "token"
    token.write_text("source-hdeem-node7\n")
    token.chmod(0o600)
    s = load_source_settings(None, env={"HDEEM_WATCH_METRICQ_TOKEN_FILE": str(token)}, overrides={"server": "amqp://x/"})
    assert s.token == "source-hdeem-node7"


@pytest.mark.slow
@pytest.mark.timeout(120)
async def test_stream_reader_reads_a_curve_daemon_with_its_key(tmp_path: Path, daemon_fixtures: Any) -> None:
    """A daemon with CURVE on TCP: the reader with the daemon's public key gets its stream, one without nothing."""
    import asyncio
    import subprocess

    from hdeem_watch.metricq.settings import SourceSettings
    from hdeem_watch.metricq.source import curve_options
    from hdeem_watch.metricq.stream import StreamReader
    from hdeem_watch.wire.keys import generate_keys, load_public_key

    public, secret = generate_keys(tmp_path / "keys", "server")
    d = daemon_fixtures.make_daemon(tmp_path / "d", "--curve-secret-key", str(secret), tcp=True)
    with open(d.stderr_path, "ab") as err:  # a plain readiness ping would be refused: start by hand
        d.proc = subprocess.Popen(d.command(), env=d.env, stdout=subprocess.DEVNULL, stderr=err)
    options = curve_options(SourceSettings(server="amqp://x/", curve_server_key_file=str(public)))
    assert options["curve_server_key"] == load_public_key(public)
    keyed, plain = StreamReader([d.pub], **options), StreamReader([d.pub])
    try:
        messages = await keyed.receive(timeout_s=30.0)
        assert messages and all(m.node == d.node for m in messages)
        assert await plain.receive(timeout_s=1.0) == []
    finally:
        keyed.close()
        plain.close()
        assert await asyncio.to_thread(d.terminate) == 0, d.stderr()


def test_each_pairs_own_fit_is_published_beside_the_nodes() -> None:
    """The calib body's per-group fits (one per DIMM pair) become that pair's current metrics, with
    the pair in the metadata; a group without a fit yet publishes nothing."""
    tr = StreamTranslator(MetricNames("s"))
    groups = {"DDR_CD": {"fit": {"currents": {"idd3n": {"calibrated": 0.093}}}}, "DDR_AB": {"fit": None}}
    out = tr.translate(body("n1", "calib", {"fit": None, "memspec": "ddr4", "groups": groups}, t_ns=9_000))
    values = {p.metric: (p.t_ns.tolist(), p.values.tolist()) for p in out.points}
    assert values == {"s.n1.dram.cd.calibrated.idd3n.current": ([9_000], [0.093])}
    meta = out.declarations["s.n1.dram.cd.calibrated.idd3n.current"]
    assert meta["channel"] == "DDR_CD" and meta["unit"] == "A" and "DIMM pair CD" in meta["description"]
