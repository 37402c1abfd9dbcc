"""Which endpoints stay on the node, and which one another node should use (stdlib only: the
settings check them without loading ZeroMQ).

The documented TCP ports of a node daemon are :data:`STREAM_PORT` (5590) and :data:`CONTROL_PORT`
(5591), everywhere: docs, the example config, the SLURM hooks, ``tui --slurm``.

Example:
    >>> is_loopback("tcp://127.0.0.1:5590"), is_loopback("tcp://*:5590"), is_loopback("ipc:///run/x")
    (True, False, True)
    >>> remote_endpoint("tcp://0.0.0.0:5590", "node7"), remote_endpoint("ipc:///run/x/pub.sock", "node7")
    ('tcp://node7:5590', None)
"""

from __future__ import annotations

import ipaddress

#: The documented TCP port of a daemon's stream (PUB) endpoint on cluster nodes.
STREAM_PORT = 5590
#: The documented TCP port of a daemon's control endpoint on cluster nodes.
CONTROL_PORT = 5591

_WILDCARD_HOSTS = ("*", "0.0.0.0", "::", "")


def is_loopback(endpoint: str) -> bool:
    """Whether ``endpoint`` is reachable only from this node (ipc, inproc, TCP on a loopback address).

    ``*``, ``0.0.0.0``, an interface name or a host name count as reachable from the network.
    """
    if not endpoint.startswith("tcp://"):
        return True
    host = endpoint[len("tcp://"):].rsplit(":", 1)[0]
    if ";" in host:  # tcp://source;destination: the bound (source) side decides
        host = host.split(";")[0]
    host = host.strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def remote_endpoint(endpoint: str, host: str) -> str | None:
    """The endpoint another node uses to reach a bound ``endpoint`` of this node (``host``'s name).

    A wildcard TCP bind becomes ``tcp://<host>:<port>``, a TCP bind on a routable address stays as
    it is; ipc, inproc and loopback TCP are reachable from this node only (None).
    """
    if not endpoint.startswith("tcp://") or is_loopback(endpoint):
        return None
    bound_host, _, port = endpoint[len("tcp://"):].rpartition(":")
    if bound_host.strip("[]") in _WILDCARD_HOSTS:
        return f"tcp://{host}:{port}"
    return endpoint
