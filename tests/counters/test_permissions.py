"""perf_event_paranoid and CAP_PERFMON: the verdict and its explanation."""

from __future__ import annotations

from pathlib import Path

import pytest

from hdeem_watch.counters.permissions import (
    CAP_PERFMON,
    CAP_SYS_ADMIN,
    check_access,
    probe_access,
    read_effective_capabilities,
    read_paranoid,
)

FIXTURES = Path(__file__).resolve().parent / "fixtures"


@pytest.mark.parametrize(("paranoid", "caps", "allowed"), [
    (2, 0, False), (1, 0, False), (3, 0, False), (0, 0, True), (-1, 0, True),
    (2, 1 << CAP_PERFMON, True), (4, 1 << CAP_SYS_ADMIN, True), (None, None, False)])
def test_verdict(paranoid, caps, allowed):
    """CPU-wide events need paranoid <= 0, or CAP_PERFMON / CAP_SYS_ADMIN (perf-security.rst)."""
    access = check_access(paranoid, caps)
    assert access.allowed is allowed
    if not allowed:
        assert "CAP_PERFMON" in access.explanation and "perf_event_paranoid" in access.explanation


@pytest.mark.parametrize(("proc", "allowed", "perfmon"), [
    ("proc_unprivileged", False, False), ("proc_perfmon", True, True), ("proc_paranoid0", True, False)])
def test_probe_fixture_proc_trees(proc, allowed, perfmon):
    """The probe reads the paranoid level and CapEff from the injected files."""
    root = FIXTURES / proc
    access = probe_access(root / "sys/kernel/perf_event_paranoid", root / "self/status")
    assert (access.allowed, access.cap_perfmon) == (allowed, perfmon)


def test_unreadable_files_are_unknown_not_zero(tmp_path):
    """A missing paranoid file or status is None (unknown), never 0 (which would mean 'allowed')."""
    assert read_paranoid(tmp_path / "absent") is None
    assert read_effective_capabilities(tmp_path / "absent") is None
    assert probe_access(tmp_path / "a", tmp_path / "b").allowed is False
