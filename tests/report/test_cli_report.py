"""``hdeem-watch report`` and ``demo --report`` on the command line: exit codes, one-line errors,
the missing extra, and lazy imports (the daemon never loads matplotlib)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from hdeem_watch.cli import main

SRC = str(Path(__file__).resolve().parents[2] / "src")


def _python(code: str, *args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": SRC + os.pathsep + os.environ.get("PYTHONPATH", "")}
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, env=env,
                          timeout=120, check=False)


def test_report_writes_the_page_and_says_what_has_no_data(state_dir: Path, tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    """Exit 0; stdout names the page and each missing piece of data."""
    assert main(["report", "--state-dir", str(state_dir), "--out", str(tmp_path / "r"), "--format", "svg"]) == 0
    out = capsys.readouterr().out
    assert f"{tmp_path / 'r' / 'index.html'}" in out
    assert "fig6-jobs: no data: job records" in out
    assert "fig7-holdout: no data: hold-out runs" in out  # the 60 s demo state predates hold-out runs
    assert len(list((tmp_path / "r").glob("fig*.svg"))) == 7


@pytest.mark.parametrize(("args", "message"), [
    (["--state-dir", "{tmp}/nowhere"], "no daemon state"),
    (["--runs", "{tmp}/missing.json"], "cannot read runs file"),
    (["--since", "soon"], "--since 'soon'"),
    (["--group", "DDR_QQ"], "--group 'DDR_QQ'"),
    (["--format", "gif"], "invalid choice"),
    (["--runs", "x.json", "--state-dir", "y"], "not allowed with argument"),
])
def test_bad_input_is_one_line_and_exit_2(state_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                          args: list[str], message: str) -> None:
    """Bad input: exit code 2 and one line on stderr naming what was wrong."""
    args = [a.format(tmp=tmp_path) for a in args]
    if "--state-dir" not in args and "--runs" not in args:
        args += ["--state-dir", str(state_dir)]
    assert main(["report", *args, "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1


@pytest.mark.slow
def test_without_matplotlib_one_line_and_exit_1(state_dir: Path, tmp_path: Path) -> None:
    """With matplotlib not importable, ``report`` says how to install the extra, in one line, exit 1
    (issue 28: it was 2, the bad-input code, although nothing was wrong with the input)."""
    done = _python("import sys; sys.modules['matplotlib'] = None\n"
                   "from hdeem_watch.cli import main; sys.exit(main(sys.argv[1:]))",
                   "report", "--state-dir", str(state_dir), "--out", str(tmp_path / "r"))
    assert done.returncode == 1
    assert done.stderr.strip() == ("hdeem-watch report: error: matplotlib is not installed; "
                                   "pip install 'hdeem-watch[report]'")
    assert not (tmp_path / "r").exists()


@pytest.mark.slow
def test_daemon_and_report_cli_do_not_import_matplotlib() -> None:
    """The report subcommand's parser and the daemon import no plotting library."""
    done = _python("import sys\nfrom hdeem_watch.cli import build_parser\nbuild_parser()\n"
                   "import hdeem_watch.daemon.service, hdeem_watch.report.demo\n"
                   "print('matplotlib' in sys.modules)")
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "False"


def test_demo_report_at_end(fresh_state_dir: Path, tmp_path: Path) -> None:
    """``demo --report`` writes the report of the demo's state and says where; a state it cannot
    read costs one line, not the demo. (A fresh state: the wiring is what is tested here; drawing a
    demo's data is test_build's and the slow ``test_demo_headless_with_report``'s.)"""
    import io

    from hdeem_watch.report.demo import report_at_end

    stream = io.StringIO()
    assert report_at_end(fresh_state_dir, tmp_path / "r", stream=stream)
    assert (tmp_path / "r" / "index.html").is_file()
    assert stream.getvalue() == f"demo: report written to {tmp_path / 'r' / 'index.html'} (open it in a browser)\n"
    stream = io.StringIO()
    assert not report_at_end(tmp_path / "none", tmp_path / "r2", stream=stream)
    assert stream.getvalue().startswith("demo: no report: ") and stream.getvalue().count("\n") == 1


@pytest.mark.slow
def test_demo_headless_with_report(tmp_path: Path) -> None:
    """The real demo (daemon subprocess, schedule, feed) for 8 s at 10x sim speed (~14 runs, as many
    as 20 s at speed 1 gave), then its report: runs, a fit and every figure file."""
    done = _python("import sys\nfrom hdeem_watch.cli import main; sys.exit(main(sys.argv[1:]))",
                   "demo", "--headless", "--duration", "8", "--speed", "10", "--report", str(tmp_path / "r"))
    assert done.returncode == 0, done.stderr[-2000:]
    assert f"demo: report written to {tmp_path / 'r' / 'index.html'}" in done.stdout
    assert len(list((tmp_path / "r").glob("fig*.png"))) == 7
    assert (tmp_path / "r" / "memspec-calibrated.json").exists()
