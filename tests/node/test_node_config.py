"""The ``[node]`` table in the daemon's TOML (issue 15): read by the daemon's settings, with the node's
name moved into it (TOML cannot hold a top-level ``node = "NAME"`` beside a ``[node]`` table), and
wired into the daemon: the run model's topology, the memspec logged with its reason, ``node.get``."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import pytest

from hdeem_watch.config import load_settings
from hdeem_watch.errors import InputError

ICE_LAKE = ('source = "sim"\n[node]\nname = "ice1"\nsockets = 2\ncores_per_socket = 28\n'
            'channels_per_socket = 8\ndimms_per_channel = 1\n')


def _config(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "hdeem-watchd.toml"
    path.write_text(text, encoding="utf-8")
    return path


def test_the_node_table_and_its_name(tmp_path: Path) -> None:
    """[node] holds the hardware and the name; the older top-level node = "NAME" still names the node."""
    settings = load_settings(_config(tmp_path, ICE_LAKE), env={})
    overrides = settings.node_overrides()
    assert settings.node == "ice1" and overrides.counts["cores_per_socket"] == 28
    assert load_settings(_config(tmp_path, 'node = "n7"\n'), env={}).node == "n7"
    both = load_settings(_config(tmp_path, '[daemon]\nnode = "d1"\n[node]\nsockets = 1\n'), env={})
    assert both.node == "d1" and both.node_overrides().counts == {"sockets": 1}
    assert load_settings(_config(tmp_path, 'source = "sim"\n'), env={}).node_overrides() is None


def test_the_old_name_beside_the_table_is_one_line_saying_what_to_write(tmp_path: Path) -> None:
    """node = "n7" and [node] in one file: invalid TOML, and the message says to use name = inside [node]."""
    with pytest.raises(InputError) as caught:
        load_settings(_config(tmp_path, 'node = "n7"\n[node]\nsockets = 2\n'), env={})
    message = str(caught.value)
    assert "hdeem-watchd.toml" in message and 'name = "NAME" inside [node]' in message and "\n" not in message


@pytest.mark.parametrize(("table", "expect"), [
    ("sockets = 0", r"hdeem-watchd.toml: \[node\]\.sockets = 0: expected a positive integer"),
    ("socket = 2", r"hdeem-watchd.toml: \[node\]: unknown key 'socket'"),
    ('name = ""', r"hdeem-watchd.toml \[node\]: node = ''; expected a non-empty name"),
    ("[node.dimm]\nranks = -1", r"\[node\]\.dimm\.ranks = -1: expected a positive integer"),
])
def test_bad_node_tables_name_the_file_and_key(tmp_path: Path, table: str, expect: str) -> None:
    with pytest.raises(InputError, match=expect):
        load_settings(_config(tmp_path, f"[node]\n{table}\n"), env={})


def test_a_mistyped_node_memspec_stops_the_start(tmp_path: Path) -> None:
    """[node] memspec = "nope": checked with the model's settings, named with the key."""
    with pytest.raises(InputError, match=r"\[node\]\.memspec = 'nope'"):
        load_settings(_config(tmp_path, '[node]\nmemspec = "nope"\n'), env={}, check_model=True)


def test_the_table_is_not_a_variable_or_a_key_of_its_own(tmp_path: Path) -> None:
    """node_table is file-only: HDEEM_WATCH_NODE_TABLE is ignored, node_table = ... is unknown."""
    assert load_settings(env={"HDEEM_WATCH_NODE_TABLE": "x"}).node_table is None
    with pytest.raises(InputError, match="unknown setting 'node_table'"):
        load_settings(_config(tmp_path, "node_table = 1\n"), env={})


def test_the_sim_models_the_node_table(tmp_path: Path) -> None:
    """--source sim with a [node] table: the simulated node is that node (16 DIMMs, 8 pair sensors)."""
    settings = load_settings(_config(tmp_path, ICE_LAKE), env={})
    node = settings.source_options()["node"]
    assert (node.sockets.value, node.cores_per_socket.value, node.channels_per_socket.value) == (2, 28, 8)


def test_the_daemon_models_the_configured_sim_node(node_trees: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """Start-up: the memspec and topology are logged with their reasons; node.get answers; the run model
    is built on 2 x 28 cores and 16 DIMMs (not the default 8)."""
    from hdeem_watch.daemon.shell.service import Daemon

    settings = load_settings(_config(tmp_path, ICE_LAKE), env={},
                             overrides={"state_dir": str(tmp_path / "state"), "runtime_dir": str(tmp_path / "run")})
    daemon = Daemon(settings)
    with caplog.at_level(logging.INFO, logger="hdeem_watch.daemon"):
        daemon.start()
    try:
        logged = "\n".join(r.getMessage() for r in caplog.records)
        assert "node memspec samsung-m393a1g43db0-cpb [default]: the simulated node's DIMMs" in logged
        assert "2 socket(s) x 28 cores, 8 channel(s) x 1 DIMM(s)" in logged
        reply: Any = daemon.control.handlers["node.get"]({}) if daemon.control else None
        assert reply["cores_per_socket"] == 28 and reply["topology"]["dimms"] == 16
        assert reply["memspec"]["confidence"] == "default" and "DDR_OP" in reply["sensors"]
        assert daemon.model_jobs is not None
        for future, _done, _failed in list(daemon.model_jobs.pending):
            future.exception(timeout=120)
        modeller = daemon.calibration.modeller
        assert modeller is not None and modeller.topology.dimms == 16 and modeller.topology.cores_per_socket == 28
    finally:
        daemon.close()




def test_a_saved_dmidecode_print_out_stands_in_for_root(node_trees: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """[node] dmidecode = FILE: a daemon that is not root (and `hdeem-watch node --config`) reads the DIMMs
    from a saved `dmidecode -t 17`; an unreadable file is one line naming the key, exit 2."""
    import json

    from hdeem_watch.cli import main

    fixture = node_trees / "epyc-rome-8ch"
    config = _config(tmp_path, f'[node]\ndmidecode = "{fixture / "dmidecode.txt"}"\n')
    assert main(["node", "--sysfs-root", str(fixture / "sys"), "--config", str(config), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert len(out["dimms"]) == 16 and out["memspec"]["name"] == "micron-8gb-x4-ddr4-2933"
    missing = _config(tmp_path, f'[node]\ndmidecode = "{tmp_path / "nope.txt"}"\n')
    assert main(["node", "--sysfs-root", str(fixture / "sys"), "--config", str(missing)]) == 2
    err = capsys.readouterr().err
    assert "[node].dmidecode" in err and "nope.txt" in err and err.count("\n") == 1


def test_the_daemon_detects_a_real_source_s_node_with_the_saved_print_out(node_trees: Path, tmp_path: Path) -> None:
    """A non-sim source: the daemon describes this machine (sysfs) with the DIMMs of [node] dmidecode, and the
    [node] counts over it; the memspec is the DIMMs' (a replayed recording is described by the table alone)."""
    from hdeem_watch.daemon.shell.service import Daemon

    fixture = node_trees / "skylake-sp"
    text = (f'source = "sim"\n[node]\ndmidecode = "{fixture / "dmidecode.txt"}"\nsockets = 2\n'
            'cores_per_socket = 20\n')
    settings = load_settings(_config(tmp_path, text), env={}, overrides={"state_dir": str(tmp_path / "s")})

    class Rapl:
        kind = "rapl"

    daemon = Daemon(settings)
    setup = daemon._describe_node(Rapl())  # type: ignore[arg-type]
    assert len(setup.description.dimms) == 12 and setup.memspec == "micron-8gb-x8-ddr4-2666"
    assert setup.topology is not None and (setup.topology.sockets, setup.topology.channels_per_socket) == (2, 6)
    assert setup.description.sockets.source == "config [node]"

    class Replay:
        kind = "replay"

    replayed = daemon._describe_node(Replay())  # type: ignore[arg-type]
    assert replayed.description.dimms == () and replayed.choice.confidence == "default"
