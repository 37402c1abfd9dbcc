"""hdeem-watch as a MetricQ source: the daemon's stream republished to a centre's MetricQ network.

One concept per module:

* :mod:`~hdeem_watch.metricq.naming` — metric names and metadata (pure).
* :mod:`~hdeem_watch.metricq.translate` — daemon stream messages to MetricQ data points (pure).
* :mod:`~hdeem_watch.metricq.settings` — the ``[metricq]`` TOML section, environment and flags;
  credentials from permission-checked files.
* :mod:`~hdeem_watch.metricq.outbox` — the bounded buffer between the stream and the broker.
* :mod:`~hdeem_watch.metricq.status` — the source's state, printed and written as JSON.
* :mod:`~hdeem_watch.metricq.stream` — the asynchronous ZeroMQ subscriber of the daemon's stream.
* :mod:`~hdeem_watch.metricq.source` — the MetricQ :class:`metricq.Source` and its reconnecting
  supervisor (the only module that imports the optional ``metricq`` package).

See docs/metricq.md.
"""
