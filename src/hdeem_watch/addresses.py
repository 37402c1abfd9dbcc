"""Which endpoints stay on the node (stdlib only: the settings check it without loading ZeroMQ).

Example:
    >>> is_loopback("tcp://127.0.0.1:7410"), is_loopback("tcp://*:7410"), is_loopback("ipc:///run/x")
    (True, False, True)
"""

from __future__ import annotations

import ipaddress


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
