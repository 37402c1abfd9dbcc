"""Which stream endpoint a client can reach, given a daemon's control endpoint: pure functions.

The UI is given a daemon's *control* endpoint; the daemon's ``status`` names its stream (PUB)
endpoint. A wildcard bind host (``tcp://*:5590``) means "the daemon's host"; an ``ipc://`` stream
exists only on the daemon's own machine, so a UI that reached the control socket over TCP from
elsewhere can never subscribe to it, and must say so instead of waiting.

Example:
    >>> pub_endpoint_for("tcp://node7:5591", "tcp://*:5590")
    'tcp://node7:5590'
    >>> unreachable_stream("tcp://node7:5591", "ipc:///run/hdeem-watch/pub.sock", is_local=lambda host: False)
    'the stream is ipc:///run/hdeem-watch/pub.sock, reachable only on node7: start the daemon with --pub tcp://*:PORT'
"""

from __future__ import annotations

import socket
from collections.abc import Callable, Mapping
from typing import Any

_WILDCARD_HOSTS = ("*", "0.0.0.0", "[::]", "::", "")
_LOOPBACK_HOSTS = ("localhost", "::1")


def tcp_host(endpoint: str) -> str:
    """The host of a ``tcp://host:port`` endpoint ("" for other transports)."""
    if not endpoint.startswith("tcp://"):
        return ""
    return endpoint[len("tcp://") :].rpartition(":")[0]


def pub_endpoint_for(control_endpoint: str, pub: str) -> str:
    """The PUB endpoint to connect to: a wildcard bind host is replaced by the control endpoint's host."""
    if not pub.startswith("tcp://"):
        return pub
    host, _, port = pub[len("tcp://") :].rpartition(":")
    if host in _WILDCARD_HOSTS:
        return f"tcp://{tcp_host(control_endpoint) or '127.0.0.1'}:{port}"
    return pub


def is_local_host(host: str) -> bool:
    """Whether ``host`` is this machine: loopback, this machine's hostname (short or as given), or
    an IP address bound here (tried with a UDP bind to port 0; no DNS lookup)."""
    name = socket.gethostname()
    bare = host.strip("[]")
    if bare in _LOOPBACK_HOSTS or bare.startswith("127.") or bare in (name, name.split(".")[0]):
        return True
    if bare.split(".")[0] == name.split(".")[0] and not bare.replace(".", "").isdigit():
        return True
    try:
        family = socket.AF_INET6 if ":" in bare else socket.AF_INET
        with socket.socket(family, socket.SOCK_DGRAM) as probe:
            probe.bind((bare, 0))
    except OSError:
        return False
    return True


def stream_endpoint(control_endpoint: str, endpoints: Mapping[str, Any], *,
                    is_local: Callable[[str], bool] = is_local_host) -> str:
    """The stream endpoint to subscribe to, from a daemon's ``status`` ``endpoints``.

    A client on another host takes the daemon's advertised remote stream (``endpoints.remote.pub``)
    when the bound one is ipc; otherwise the bound one, with a wildcard host replaced by the
    control endpoint's. "" when the status names none.
    """
    pub = str(endpoints.get("pub") or "")
    remote = endpoints.get("remote")
    host = tcp_host(control_endpoint)
    if (not pub.startswith("tcp://") and host and isinstance(remote, Mapping)
            and isinstance(remote.get("pub"), str) and not is_local(host)):
        pub = str(remote["pub"])
    return pub_endpoint_for(control_endpoint, pub) if pub else ""


def unreachable_stream(control_endpoint: str, pub: str, *, is_local: Callable[[str], bool] = is_local_host) -> str | None:
    """Why the stream ``pub`` cannot be reached from here, or None if it may be.

    An ``ipc://`` stream is unreachable when the control endpoint is TCP to another host.
    """
    host = tcp_host(control_endpoint)
    if not pub.startswith("ipc://") or not host or is_local(host):
        return None
    return f"the stream is {pub}, reachable only on {host}: start the daemon with --pub tcp://*:PORT"
