"""Job ids as the protocol defines them (docs/protocol.md, `job.start`): a SLURM job number with an
optional array-task or het-job suffix. Issue 28: `job.start` took "abc" and a 34-digit id."""

from __future__ import annotations

import pytest

from hdeem_watch.wire.protocol import ProtocolError
from hdeem_watch.wire.requests import job_id_arg


@pytest.mark.parametrize("value", ["4242", "4242_3", "4242+1", 4242, 0, "4294967295"])
def test_slurm_job_ids_are_taken(value: object) -> None:
    assert job_id_arg(value) == str(value)


@pytest.mark.parametrize("value", ["abc", "1" * 34, "", "42 ", "-1", "4242_", "4242_3_4", "unknown", -1, True, 4.0])
def test_what_slurm_never_names_a_job_is_refused(value: object) -> None:
    with pytest.raises(ProtocolError) as refused:
        job_id_arg(value)
    assert refused.value.code == "bad-args" and "expected a SLURM job id" in str(refused.value)
