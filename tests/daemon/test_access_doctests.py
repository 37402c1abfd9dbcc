"""The examples in the docstrings of the access modules run and hold (authorization, handshake
explanations, keys, endpoints a remote client uses, the control server and client)."""

from __future__ import annotations

import doctest
import importlib

import pytest

MODULES = ("hdeem_watch.daemon.shell.authorization", "hdeem_watch.wire.handshake", "hdeem_watch.daemon.shell.security", "hdeem_watch.wire.keys",
           "hdeem_watch.addresses", "hdeem_watch.wire.discovery", "hdeem_watch.daemon.shell.control",
           "hdeem_watch.wire.client", "hdeem_watch.wire.subscriber")


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name: str) -> None:
    result = doctest.testmod(importlib.import_module(name))
    assert result.failed == 0 and result.attempted > 0
