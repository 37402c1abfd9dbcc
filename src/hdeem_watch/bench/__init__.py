"""Benchmark suite: STREAM-like stride-8 kernels and an idle kernel on pinned workers.

Modules: :mod:`~hdeem_watch.bench.schedule` (run lists), :mod:`~hdeem_watch.bench.kernels` (the
kernels, pure numpy), :mod:`~hdeem_watch.bench.system` (CPUs, topology, LLC, memory),
:mod:`~hdeem_watch.bench.runner` (workers and measurement), :mod:`~hdeem_watch.bench.announce`
(run.start/run.stop to the daemon). The command line is ``hdeem-watch bench`` (docs/bench.md).
"""
