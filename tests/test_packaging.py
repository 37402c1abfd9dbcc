"""The release: a LICENSE matching pyproject, and a wheel that installs into a fresh venv and runs
the demo (issue 28: docs/slurm.md tells admins to `pip install hdeem-watch`)."""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_the_license_file_is_the_one_pyproject_names() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["license"] == "BSD-3-Clause" and project["license-files"] == ["LICENSE"]
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("BSD 3-Clause License") and "Neither the name of the copyright holder" in text


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_the_wheel_installs_into_a_fresh_venv_and_runs_the_demo(tmp_path: Path) -> None:
    """`python -m build` gives a wheel with the C shim's source, the memspec presets, the examples
    and the LICENSE; installed into a fresh venv (the system's packages visible, so nothing is
    downloaded but the build backend) it runs `hdeem-watch demo --headless --duration 2` from
    its own copy, not from this checkout (2 s of it: the copy runs, starts its daemon and ends cleanly)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    subprocess.run([sys.executable, "-m", "build", "--wheel", "--outdir", str(tmp_path / "dist"), str(ROOT)],
                   check=True, capture_output=True, timeout=300, env=env)
    (wheel,) = (tmp_path / "dist").glob("hdeem_watch-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert "hdeem_watch/sources/hdeem_shim.c" in names
    assert "hdeem_watch/dram/presets/samsung-m393a1g43db0-cpb.json" in names
    assert any(n.endswith("/licenses/LICENSE") for n in names)
    examples = [n for n in names if "/share/hdeem-watch/examples/" in n]
    assert {Path(n).name for n in examples} >= {"RUNS.json", "recording-runs.csv", "memspec.json", "README.md"}
    venv = tmp_path / "venv"
    # no pip of its own (ensurepip took 3-6 s): this interpreter's pip installs into it (--python)
    subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", "--without-pip", str(venv)], check=True,
                   timeout=120)
    subprocess.run([sys.executable, "-m", "pip", "--python", str(venv / "bin" / "python"), "install", "-q",
                    "--disable-pip-version-check", str(wheel)], check=True, capture_output=True, timeout=300, env=env)
    where = subprocess.run([str(venv / "bin" / "python"), "-c", "import hdeem_watch; print(hdeem_watch.__file__)"],
                           check=True, capture_output=True, text=True, cwd=tmp_path, env=env).stdout
    assert where.startswith(str(venv))
    assert (venv / "share" / "hdeem-watch" / "examples" / "RUNS.json").is_file()
    demo = subprocess.run([str(venv / "bin" / "hdeem-watch"), "demo", "--headless", "--duration", "2"],
                          capture_output=True, text=True, cwd=tmp_path, env=env, timeout=120)
    assert demo.returncode == 0, demo.stderr
    assert "demo: done after" in demo.stdout
