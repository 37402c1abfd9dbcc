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


def host(trees: Path, sysfs: str, cpuinfo: str, proc: str = "proc_perfmon") -> list[str]:
    return ["--sysfs-root", str(trees / sysfs), "--cpuinfo", str(FIXTURES / "cpuinfo" / cpuinfo),
            "--proc-root", str(FIXTURES / proc)]


def test_haswell_ep_json(pmu_trees, capsys):
    """Haswell-EP: 8 channels as (socket, box), 14 events for 2 ranks, encoded; the JSON parses."""
    code, out, _ = run(capsys, *host(pmu_trees, "sysfs_haswell_ep", "haswell_ep"), "--json")
    data = json.loads(out)
    assert code == 0 and data["usable"] and data["generation"] == "haswell-ep"
    assert [c["name"] for c in data["channels"]][:4] == ["S0.imc0", "S0.imc1", "S0.imc4", "S0.imc5"]
    assert {c["cpu"] for c in data["channels"]} == {0, 12} and len(data["channels"]) == 8
    events = {e["name"]: e for e in data["events"]}
    assert len(events) == 14 and "UNC_M_POWER_CKE_CYCLES.RANK2" not in events
    assert events["UNC_M_CAS_COUNT.WR"]["config"] == "0xc04"
    assert data["event_sources"] == ["HSX/events/haswellx_uncore.json V29"]
    assert any("multiplexes" in note for note in data["notes"])


def test_ice_lake_sp_text(pmu_trees, capsys):
    """Ice Lake-SP: 24 channels, free-running PMUs listed as not used, RDA/WRA events present."""
    code, out, _ = run(capsys, *host(pmu_trees, "sysfs_ice_lake_sp", "ice_lake_sp"))
    assert code == 0
    assert "channels: 24" in out and "free-running (not used)" in out
    assert "UNC_M_CAS_COUNT.WR_PRE" in out and "status: ready to count" in out


def test_this_vm_situation(pmu_trees, capsys):
    """The VM fixture: exit 0, the Zen 5 table of its host CPU (family 26 model 2, Turin), but no amd_umc PMU:
    a guest gets none; the PMUs it does have are listed."""
    code, out, _ = run(capsys, *host(pmu_trees, "sysfs_vm", "vm_amd_epyc"), "--json")
    data = json.loads(out)
    assert code == 0 and not data["usable"] and data["generation"] == "zen5"
    assert data["other_pmus"] == ["breakpoint", "msr", "software", "tracepoint", "uprobe"]
    assert any("no amd_umc_* PMU" in r and "Virtual machines" in r for r in data["reasons"])
    assert len(data["reasons"]) == 1 and data["channels"] == []


def test_sapphire_rapids_json(pmu_trees, capsys):
    """SPR: 16 channels (2 sockets x uncore_imc_0..7), CAS per pseudo-channel, the underfill precharges, and
    perf's names: cas_count_read/write are ours; its clockticks (0x01/0x00) is not our dclk (0x01/0x01)."""
    code, out, _ = run(capsys, *host(pmu_trees, "sysfs_sapphire_rapids", "sapphire_rapids"), "--json")
    data = json.loads(out)
    assert code == 0 and data["usable"] and data["generation"] == "sapphire-rapids"
    assert len(data["channels"]) == 16 and {c["cpu"] for c in data["channels"]} == {0, 56}
    events = {e["name"]: e for e in data["events"]}
    for name in ("UNC_M_CAS_COUNT.PCH0", "UNC_M_CAS_COUNT.PCH1", "UNC_M_PRE_COUNT.UFILL", "UNC_M_PRE_COUNT.RD",
                 "UNC_M_PRE_COUNT.WR", "UNC_M_PRE_COUNT.PGT", "UNC_M_CLOCKTICKS"):
        assert name in events, name
    assert events["UNC_M_PRE_COUNT.UFILL"]["config"] == "0x4403"
    assert events["UNC_M_CAS_COUNT.RD"]["perf_alias"] == "cas_count_read"
    assert events["UNC_M_CAS_COUNT.WR"]["perf_alias"] == "cas_count_write"
    assert events["UNC_M_CLOCKTICKS"]["perf_alias"] is None
    assert any("clockticks" in n and "UNC_M_HCLOCKTICKS" in n for n in data["notes"])


def test_genoa_json(pmu_trees, capsys):
    """Genoa: 24 channels, one amd_umc PMU each, socket from the counting CPU; the Zen 4 umc events encoded in
    event and rdwrmask; the DRAM energy is modelled (no sensor), and the notes say so."""
    code, out, _ = run(capsys, *host(pmu_trees, "sysfs_genoa", "genoa"), "--json")
    data = json.loads(out)
    assert code == 0 and data["usable"] and data["generation"] == "zen4"
    channels = data["channels"]
    assert len(channels) == 24 and channels[0]["name"] == "S0.umc0" and channels[12]["name"] == "S1.umc12"
    assert {c["cpu"] for c in channels if c["socket"] == 1} == {96}
    events = {e["name"]: e for e in data["events"]}
    assert set(events) == {"umc_mem_clk", "umc_cas_cmd.rd", "umc_cas_cmd.wr", "umc_act_cmd.all", "umc_pchg_cmd.all"}
    assert events["umc_cas_cmd.wr"]["config"] == "0x20a" and events["umc_cas_cmd.rd"]["config"] == "0x10a"
    assert events["umc_act_cmd.all"]["config"] == "0x5" and events["umc_pchg_cmd.all"]["config"] == "0x6"
    assert data["event_sources"] == ["tools/perf/pmu-events/arch/x86/amdzen4/memory-controller.json"]
    assert any("no DRAM energy sensor" in n and "datasheet" in n and "calibrated memspec" in n for n in data["notes"])
    assert "amd_df" in data["other_pmus"] and not any(p.startswith("amd_umc") for p in data["other_pmus"])


def test_genoa_text(pmu_trees, capsys):
    """The text report lists the UMC events with their rdwrmask and the perf JSON they come from."""
    code, out, _ = run(capsys, *host(pmu_trees, "sysfs_genoa", "genoa"))
    assert code == 0 and "channels: 24" in out and "status: ready to count" in out
    assert "umc_cas_cmd.rd" in out and "rdwrmask 0x01" in out and "amdzen4/memory-controller.json" in out


def test_permissions_explained(pmu_trees, capsys):
    """An unprivileged process on a real host: not usable, with paranoid level, CAP_PERFMON and the fix."""
    code, out, _ = run(capsys, *host(pmu_trees, "sysfs_haswell_ep", "haswell_ep", proc="proc_unprivileged"))
    assert code == 0 and "cannot count on this host" in out
    assert "perf_event_paranoid = 2" in out and "CAP_PERFMON" in out and "AmbientCapabilities" in out
    assert "events per channel: 14" in out  # what it would use is still listed


def test_bad_input_is_one_line_exit_2(pmu_trees, capsys, tmp_path):
    """A missing cpuinfo or a malformed PMU directory: one line on stderr, exit code 2, no traceback."""
    code, _, err = run(capsys, "--sysfs-root", str(pmu_trees / "sysfs_haswell_ep"), "--cpuinfo", str(tmp_path / "x"))
    assert code == 2 and err.count("\n") == 1 and "cannot read" in err
    bad = tmp_path / "sysfs/bus/event_source/devices/uncore_imc_0"
    (bad / "format").mkdir(parents=True)
    (bad / "type").write_text("13\n")
    (bad / "cpumask").write_text("0\n")
    (bad / "format/umask").write_text("config:15-8\n")
    code, _, err = run(capsys, "--sysfs-root", str(tmp_path / "sysfs"),
                       "--cpuinfo", str(FIXTURES / "cpuinfo/haswell_ep"))
    assert code == 2 and "uncore_imc_0/format/umask" in err and "Traceback" not in err
    code, _, err = run(capsys, *host(pmu_trees, "sysfs_haswell_ep", "haswell_ep"), "--ranks", "9")
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
