"""Fixtures of the TUI tests: real publishers on ipc sockets in a short temporary directory."""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest

from hdeem_watch.tui.fakenode import FakeNode


@pytest.fixture
def sock_dir() -> Iterator[Path]:
    """A short directory for ipc sockets (ipc paths are limited to ~100 bytes)."""
    path = Path(tempfile.mkdtemp(prefix="hwt-", dir="/tmp"))
    try:
        yield path
    finally:
        shutil.rmtree(path, ignore_errors=True)


@pytest.fixture
def fake_node(sock_dir: Path) -> Iterator[FakeNode]:
    """A wire-protocol publisher at HDEEM rates with a control socket."""
    node = FakeNode("fake1", f"ipc://{sock_dir}/f1-pub", f"ipc://{sock_dir}/f1-ctl").start_and_wait()
    try:
        yield node
    finally:
        node.stop()


def pytest_configure(config: pytest.Config) -> None:  # pragma: no cover - environment only
    os.environ.setdefault("TEXTUAL_ANIMATIONS", "none")
