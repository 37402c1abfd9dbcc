"""Bad input is one line naming what was wrong, exit 2, no traceback (issue 28, "Errors, flags,
words"): each case below was a traceback, a wrong exit code or a wrong name before."""

from __future__ import annotations

from pathlib import Path

import pytest

from hdeem_watch.cli import main


def _one_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err.strip()


def test_demo_checks_its_directories_before_it_starts(capsys: pytest.CaptureFixture[str]) -> None:
    """`demo --state-dir /proc/nope` was a FileNotFoundError; `demo --report /proc/nope` was checked
    only after the run (exit 0)."""
    assert main(["demo", "--headless", "--duration", "1", "--state-dir", "/proc/nope"]) == 2
    assert _one_line(capsys) == ("hdeem-watch: error: --state-dir /proc/nope: cannot create the directory "
                                 "(No such file or directory)")
    assert main(["demo", "--headless", "--duration", "1", "--report", "/proc/nope/r"]) == 2
    assert "--report /proc/nope/r: cannot create the directory" in _one_line(capsys)


def test_demo_refuses_a_pair_the_sim_does_not_have(capsys: pytest.CaptureFixture[str]) -> None:
    """`demo --sim-age DDR_XX=+30%/h` started the daemon, which failed: exit 1; now bad input, exit 2."""
    assert main(["demo", "--headless", "--duration", "1", "--sim-age", "DDR_XX=+30%/h"]) == 2
    assert "'DDR_XX' is not a DRAM sensor" in _one_line(capsys)


@pytest.mark.parametrize(("config", "env", "flags", "message"), [
    ("sndhwm = 99999999999999999999\n", {}, [], "sndhwm = 99999999999999999999; expected 1..2147483647"),
    ("", {"HDEEM_WATCH_SNDHWM": "99999999999999999999"}, [], "environment HDEEM_WATCH_SNDHWM: sndhwm ="),
    ("", {}, ["--speed", "1e308"], "--speed: speed = 1e+308; expected a time factor up to 1e+06"),
    ("", {}, ["--prometheus", "99999"], "--prometheus: prometheus_port = 99999; expected 0..65535"),
    ("node = 5\n", {}, [], "node = 5; expected a string in quotes"),
    ('node = "a"\n[daemon]\nnode = "b"\n', {}, [], "node is set twice, at the top ('a') and in [daemon] ('b')"),
])
def test_daemon_settings_out_of_range(config: str, env: dict[str, str], flags: list[str], message: str,
                                      tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    """OverflowError tracebacks (sndhwm), an accepted 1e308 speed, the flag named by its field
    (--prometheus-port), node = 5 taken as "5" and a node set twice are one line, exit 2."""
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    path = tmp_path / "d.toml"
    path.write_text(config)
    argv = ["daemon", *(["--config", str(path)] if config else []), "--state-dir", str(tmp_path / "s"), *flags]
    assert main(argv) == 2
    assert message in _one_line(capsys)


def test_a_damaged_sysfs_capture_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`node --sysfs-root` with core_id = zz was a ValueError."""
    topology = tmp_path / "devices/system/cpu/cpu0/topology"
    topology.mkdir(parents=True)
    (topology / "core_id").write_text("zz\n")
    (topology / "physical_package_id").write_text("0\n")
    assert main(["node", "--sysfs-root", str(tmp_path)]) == 2
    assert _one_line(capsys).endswith("core_id: 'zz' is not a number; expected the kernel's topology id")


def test_counters_refuses_a_missing_sysfs_root_like_node(capsys: pytest.CaptureFixture[str]) -> None:
    """`counters --sysfs-root /nonexistent` printed a plan and exited 0; `node` says exit 2."""
    assert main(["counters", "--sysfs-root", "/nonexistent"]) == 2
    assert _one_line(capsys) == "hdeem-watch: error: --sysfs-root /nonexistent: not a directory"


def test_no_doubled_prefix(capsys: pytest.CaptureFixture[str]) -> None:
    """'hdeem-watch: error: hdeem-watch: unrecognized arguments' said the name twice."""
    assert main(["bench", "--bogus"]) == 2
    assert _one_line(capsys) == "hdeem-watch: error: unrecognized arguments: --bogus"
    assert main(["bench", "--threads"]) == 2
    assert _one_line(capsys) == "hdeem-watch: error: bench: argument --threads: expected one argument"


def test_node_does_not_advise_a_flag_it_lacks() -> None:
    """`node` advised '--memspec', which only the daemon has."""
    from hdeem_watch.node.memspec_choice import choose_memspec

    assert choose_memspec([]).reason.endswith("(or the daemon's --memspec)")


def test_one_run_is_not_one_runs() -> None:
    """Issue 28: "1 runs"."""
    from hdeem_watch.cli.calib import format_fits

    assert format_fits({"node": {"fit": None, "runs": 1}}, [], []) == "node: no fit yet (1 run)"
    assert format_fits({"node": {"fit": None, "runs": 2}}, [], []) == "node: no fit yet (2 runs)"


def test_metricq_source_takes_the_stream_not_connect(capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 28: one meaning per flag: `--connect` is a control endpoint in every command;
    metricq-source reads the stream, named --stream (and --server-key like every client)."""
    assert main(["metricq-source", "--server", "amqp://localhost/", "--connect", "tcp://node7:5590"]) == 2
    assert "use --stream" not in (err := _one_line(capsys)) and "give its stream endpoint with --stream EP" in err
    from hdeem_watch.cli import build_parser

    args = build_parser("metricq_source").parse_args(["metricq-source", "--stream", "ipc:///x", "--server-key", "k"])
    assert args.connect == ["ipc:///x"] and args.curve_server_key == "k"


@pytest.mark.slow
def test_metricq_source_that_never_reached_the_broker_exits_1(capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 28: a source that never reached its broker exited 0."""
    assert main(["metricq-source", "--server", "amqp://127.0.0.1:9/", "--stream", "ipc:///nonexistent/pub.sock",
                 "--duration", "2"]) == 1
    assert "never reached the MetricQ broker" in capsys.readouterr().err


def test_a_port_conflict_on_remote_control_names_that_flag(tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 28: a port taken on --remote-control was blamed on the pub and control endpoints."""
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        assert main(["daemon", "--runtime-dir", str(tmp_path / "r"), "--state-dir", str(tmp_path / "s"),
                     "--remote-control", f"tcp://127.0.0.1:{port}"]) == 2
    assert _one_line(capsys) == (f"hdeem-watch: error: --remote-control tcp://127.0.0.1:{port}: cannot bind: "
                                 "Address already in use")


def test_calib_show_prints_intervals_one_way() -> None:
    """Issue 28: `calib show` printed `[—, —]` for some groups and numbers for others; an interval is
    `[lo, hi]` in mA or "no interval", explained once."""
    from hdeem_watch.cli.calib import format_fits

    fit = {"n_runs": 9, "status": "ok", "error": {"loo": 0.01}, "currents": {
        "idd0": {"calibrated": 0.05, "ci95": [0.045, 0.055], "datasheet": 0.1, "identifiable": True},
        "idd4w": {"calibrated": 0.08, "ci95": None, "datasheet": 0.16, "identifiable": False}}}
    lines = format_fits({"node": {"fit": fit}, "DDR_AB": {"fit": fit}}, [], []).splitlines()
    assert "[45.00, 55.00]" in lines[1] and "—" not in "\n".join(lines)
    assert "no interval" in lines[2] and lines[-1].startswith("no interval: the fit gives none")
    assert lines[1].index("datasheet") == lines[2].index("datasheet")


def test_calib_show_prints_each_sockets_value_where_the_node_is_fitted_per_socket() -> None:
    """A node with one DRAM sensor per socket (RAPL, DDR5) has its currents as the sockets' mean:
    `calib show` prints each socket's own value under the node's, starred where that socket's fit
    leaves it undetermined; a fit without sockets prints no such block."""
    from hdeem_watch.cli.calib import format_fits

    currents = {"idd0": {"calibrated": 0.051, "ci95": [0.048, 0.054], "datasheet": 0.1, "identifiable": True},
                "idd2n": {"calibrated": 0.03, "ci95": None, "datasheet": 0.05, "identifiable": False}}
    per_socket = {"DRAM0": {"idd0": {"calibrated": 0.050, "identifiable": True},
                            "idd2n": {"calibrated": 0.029, "identifiable": False}},
                  "DRAM1": {"idd0": {"calibrated": 0.052, "identifiable": True},
                            "idd2n": {"calibrated": "?", "identifiable": False}}}
    fit = {"n_runs": 40, "status": "ok", "error": {"loo": 0.02}, "currents": currents,
           "trust": {"commands": "counted", "held": {}, "per_socket": per_socket}}
    lines = format_fits({"node": {"fit": fit}}, [], []).splitlines()
    start = next(i for i, line in enumerate(lines) if line.strip().startswith("per socket"))
    assert lines[start + 1].split() == ["idd0", "DRAM0", "50.00", "DRAM1", "52.00"]
    assert lines[start + 2].split() == ["idd2n", "DRAM0", "29.00*", "DRAM1", "—*"]
    plain = format_fits({"node": {"fit": {**fit, "trust": {"commands": "counted", "held": {}}}}}, [], [])
    assert "per socket" not in plain
