"""Why a connection to the daemon fails before any reply: ZeroMQ's handshake events, explained.

ZeroMQ hides a failed security handshake (a CURVE key the daemon does not accept, a wrong server
key, CURVE on one side only): the socket just reconnects forever and requests wait. A socket
monitor sees the events; :func:`explain` turns the decisive ones into one line, and a
:class:`HandshakeWatch` reads them next to a client socket, so a client fails within a round trip
with the reason instead of waiting for its timeout.

Example:
    >>> print(explain(zmq.EVENT_HANDSHAKE_FAILED_AUTH, 400, curve=True))
    the daemon refused this client's CURVE key (not registered in its curve_clients_dir)
    >>> explain(zmq.EVENT_CONNECTED, 0, curve=True) is None
    True
"""

from __future__ import annotations

import contextlib
from typing import Any

import zmq
from zmq.utils.monitor import recv_monitor_message

#: libzmq's ZMQ_PROTOCOL_ERROR_ZMTP_MECHANISM_MISMATCH: one side speaks CURVE, the other not.
MECHANISM_MISMATCH = 0x11000002

#: The events a watch listens to.
WATCHED_EVENTS = (zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL | zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL
                  | zmq.EVENT_HANDSHAKE_FAILED_AUTH | zmq.EVENT_HANDSHAKE_SUCCEEDED)

_SERVER_KEY_HINT = "--server-key FILE, $HDEEM_WATCH_SERVER_KEY, or curve_public_key_file in the daemon's config"


def explain(event: int, value: int, *, curve: bool) -> str | None:
    """One line for a decisive handshake failure, None for any other event.

    Args:
        event: the monitor event (``zmq.EVENT_*``).
        value: its value (a ZAP status code, a protocol error code or an errno).
        curve: whether this client uses CURVE.
    """
    if event == zmq.EVENT_HANDSHAKE_FAILED_AUTH:
        if value == 400:
            return "the daemon refused this client's CURVE key (not registered in its curve_clients_dir)"
        return f"the daemon refused this client's credentials (ZAP status {value})"
    if event == zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL and value == MECHANISM_MISMATCH:
        if curve:
            return "the daemon does not use CURVE on this endpoint (drop the server key)"
        return f"the daemon requires CURVE: give its public key ({_SERVER_KEY_HINT})"
    if event == zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL:
        return f"the security handshake failed (ZeroMQ protocol error {value:#x})"
    if event == zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL:
        # The daemon closed the connection in the handshake; the client often sees only the closed
        # pipe (EPIPE), not the daemon's reason. A client without CURVE fails only against CURVE.
        if curve:
            return ("the daemon closed the CURVE handshake: the server key given is not this daemon's "
                    f"({_SERVER_KEY_HINT}), or it does not use CURVE here")
        return f"the daemon requires CURVE: give its public key ({_SERVER_KEY_HINT})"
    return None


class HandshakeWatch:
    """A monitor on one client socket that remembers the first decisive handshake failure.

    Args:
        sock: the client socket (before it connects).
        curve: whether it uses CURVE (chooses the wording).

    Attributes:
        socket: the monitor's socket (poll it for ``POLLIN``, then call :meth:`read`).
        failure: the reason of the last failed handshake (None after a success).
    """

    def __init__(self, sock: zmq.Socket[Any], *, curve: bool) -> None:
        self._client = sock
        self.curve = curve
        self.socket: zmq.Socket[Any] = sock.get_monitor_socket(WATCHED_EVENTS)
        self.failure: str | None = None

    def read(self) -> str | None:
        """Take the waiting events; return the failure they show (None if none)."""
        failure = None
        while self.socket.poll(0):
            try:
                message = recv_monitor_message(self.socket, zmq.NOBLOCK)
            except zmq.Again:
                break
            event, value = int(message["event"]), int(message["value"])
            if event == zmq.EVENT_HANDSHAKE_SUCCEEDED:
                self.failure = failure = None
                continue
            reason = explain(event, value, curve=self.curve)
            if reason is not None:
                self.failure = failure = reason
        return failure

    def close(self) -> None:
        """Stop monitoring and close the monitor's socket (before the client socket closes)."""
        with contextlib.suppress(zmq.ZMQError):
            self._client.disable_monitor()
        self.socket.close(linger=0)
