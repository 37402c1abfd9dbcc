"""Tests of the benchmark schedule (thread specs, kernel names, sweeps)."""

from __future__ import annotations

import pytest

from hdeem_watch.bench.schedule import ALL_KERNELS, KERNELS, RunSpec, parse_kernels, parse_threads, sweep
from hdeem_watch.errors import InputError


def test_parse_threads_ranges_and_steps() -> None:
    """A spec mixes counts and inclusive ranges with steps, in the order given."""
    assert parse_threads("1,2,4-24:4") == [1, 2, 4, 8, 12, 16, 20, 24]
    assert parse_threads("3") == [3]
    assert parse_threads(" 2 - 5 ") == [2, 3, 4, 5]
    assert parse_threads("4,1-4") == [4, 1, 2, 3]


@pytest.mark.parametrize("spec", ["", " ", "0", "-1", "a", "1,,2", "5-2", "1-8:0", "4:2", "1-x", "99999"])
def test_parse_threads_rejects_bad_specs(spec: str) -> None:
    """Bad thread specs raise a one-line InputError naming the spec."""
    with pytest.raises(InputError) as info:
        parse_threads(spec)
    assert "\n" not in str(info.value)
    assert "--threads" in str(info.value)


def test_parse_kernels_aliases_and_all() -> None:
    """'addition' is an alias of 'add'; 'all' is the seven kernels; unknown names fail."""
    assert parse_kernels("Read,addition,idle") == ["read", "add", "idle"]
    assert parse_kernels("all") == list(KERNELS)
    assert parse_kernels("all+idle") == [*KERNELS, "idle"]  # the hold-out kernels only by name or "holdout"
    assert set(ALL_KERNELS) == {*KERNELS, "idle", "gups", "chase", "stride2", "stride4", "mix31"}
    with pytest.raises(InputError):
        parse_kernels("stream")
    with pytest.raises(InputError):
        parse_kernels(",")


def test_sweep_is_kernel_major() -> None:
    """A sweep lists every kernel × thread count, kernels outermost, with the run parameters."""
    runs = sweep(["read", "copy"], "1-2", 1024, 3)
    assert runs == [RunSpec("read", 1, 1024, 3), RunSpec("read", 2, 1024, 3),
                    RunSpec("copy", 1, 1024, 3), RunSpec("copy", 2, 1024, 3)]
    assert runs[0].to_dict() == {"kernel": "read", "threads": 1, "elements": 1024, "repeat": 3}


def test_sweep_rejects_bad_sizes() -> None:
    """Elements below one line and repeat below 1 are input errors."""
    with pytest.raises(InputError):
        sweep("read", "1", 4, 1)
    with pytest.raises(InputError):
        sweep("read", "1", 1024, 0)
