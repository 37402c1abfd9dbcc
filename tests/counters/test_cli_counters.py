"""``hdeem-watch counters`` on fixture hosts and on this machine."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from hdeem_watch.cli import main

FIXTURES = Path(__file__).resolve().parent / "fixtures"


def run(capsys, *args: str) -> tuple[int, str, str]:
    code = main(["counters", *args])
    out, err = capsys.readouterr()
    return code, out, err


def host(sysfs: str, cpuinfo: str, proc: str = "proc_perfmon") -> list[str]:
    return ["--sysfs-root", str(FIXTURES / sysfs), "--cpuinfo", str(FIXTURES / "cpuinfo" / cpuinfo),
            "--proc-root", str(FIXTURES / proc)]


def test_haswell_ep_json(capsys):
    """Haswell-EP: 8 channels as (socket, box), 14 events for 2 ranks, encoded; the JSON parses."""
    code, out, _ = run(capsys, *host("sysfs_haswell_ep", "haswell_ep"), "--json")
    data = json.loads(out)
    assert code == 0 and data["usable"] and data["generation"] == "haswell-ep"
    assert [c["name"] for c in data["channels"]][:4] == ["S0.imc0", "S0.imc1", "S0.imc4", "S0.imc5"]
    assert {c["cpu"] for c in data["channels"]} == {0, 12} and len(data["channels"]) == 8
    events = {e["name"]: e for e in data["events"]}
    assert len(events) == 14 and "UNC_M_POWER_CKE_CYCLES.RANK2" not in events
    assert events["UNC_M_CAS_COUNT.WR"]["config"] == "0xc04"
    assert data["event_sources"] == ["HSX/events/haswellx_uncore.json V29"]
    assert any("multiplexes" in note for note in data["notes"])


def test_ice_lake_sp_text(capsys):
    """Ice Lake-SP: 24 channels, free-running PMUs listed as not used, RDA/WRA events present."""
    code, out, _ = run(capsys, *host("sysfs_ice_lake_sp", "ice_lake_sp"))
    assert code == 0
    assert "channels: 24" in out and "free-running (not used)" in out
    assert "UNC_M_CAS_COUNT.WR_PRE" in out and "status: ready to count" in out


def test_this_vm_situation(capsys):
    """The VM fixture: exit 0, no IMC PMU, the PMUs it does have, and no event table for the AMD CPU."""
    code, out, _ = run(capsys, *host("sysfs_vm", "vm_amd_epyc"), "--json")
    data = json.loads(out)
    assert code == 0 and not data["usable"]
    assert data["other_pmus"] == ["breakpoint", "msr", "software", "tracepoint", "uprobe"]
    assert any("no uncore_imc_* PMU" in r and "Virtual machines" in r for r in data["reasons"])
    assert any("AuthenticAMD-26-2" in r for r in data["reasons"])


def test_permissions_explained(capsys):
    """An unprivileged process on a real host: not usable, with paranoid level, CAP_PERFMON and the fix."""
    code, out, _ = run(capsys, *host("sysfs_haswell_ep", "haswell_ep", proc="proc_unprivileged"))
    assert code == 0 and "cannot count on this host" in out
    assert "perf_event_paranoid = 2" in out and "CAP_PERFMON" in out and "AmbientCapabilities" in out
    assert "events per channel: 14" in out  # what it would use is still listed


def test_bad_input_is_one_line_exit_2(capsys, tmp_path):
    """A missing cpuinfo or a malformed PMU directory: one line on stderr, exit code 2, no traceback."""
    code, _, err = run(capsys, "--sysfs-root", str(FIXTURES / "sysfs_haswell_ep"), "--cpuinfo", str(tmp_path / "x"))
    assert code == 2 and err.count("\n") == 1 and "cannot read" in err
    bad = tmp_path / "sysfs/bus/event_source/devices/uncore_imc_0"
    (bad / "format").mkdir(parents=True)
    (bad / "type").write_text("13\n")
    (bad / "cpumask").write_text("0\n")
    (bad / "format/umask").write_text("config:15-8\n")
    code, _, err = run(capsys, "--sysfs-root", str(tmp_path / "sysfs"),
                       "--cpuinfo", str(FIXTURES / "cpuinfo/haswell_ep"))
    assert code == 2 and "uncore_imc_0/format/umask" in err and "Traceback" not in err
    code, _, err = run(capsys, *host("sysfs_haswell_ep", "haswell_ep"), "--ranks", "9")
    assert code == 2 and "ranks = 9" in err


@pytest.mark.slow
@pytest.mark.parametrize("flag", [[], ["--json"]])
def test_on_this_machine_as_a_process(flag):
    """The real host, as a real process: exit 0 either way (counting possible or explained)."""
    result = subprocess.run([sys.executable, "-m", "hdeem_watch", "counters", *flag],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    if flag:
        data = json.loads(result.stdout)
        assert data["usable"] is (not data["reasons"])
    else:
        assert "status: " in result.stdout
