"""hdeem_watch.wire: the daemon's wire protocol, as every client and the daemon itself speak it.

Protocol v1 (topics, stream messages, control requests and replies, strict JSON), the control
client with the default endpoints, the CURVE keys of a client and its handshake watch. A layer
below the daemon: clients (TUI, bench, SLURM hooks, MetricQ, report, command line) import this,
never ``hdeem_watch.daemon``.
"""
