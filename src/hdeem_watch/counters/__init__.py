"""Memory-controller counters: the DRAM commands of any job, counted by the uncore IMC PMU.

Modules, one concept each:

- :mod:`~hdeem_watch.counters.event_format`: sysfs ``format/`` bit fields, parsed and used to
  encode an event's ``config`` words (no hard-coded shifts).
- :mod:`~hdeem_watch.counters.pmu_discovery`: the ``uncore_imc_*`` PMUs under an injected sysfs root.
- :mod:`~hdeem_watch.counters.cpu_identity`: CPU generation from ``/proc/cpuinfo`` (family/model).
- :mod:`~hdeem_watch.counters.event_tables`: per-generation IMC event encodings, each traceable to
  Intel's public perfmon event files.
- :mod:`~hdeem_watch.counters.permissions`: ``perf_event_paranoid`` and ``CAP_PERFMON``, explained.
- :mod:`~hdeem_watch.counters.host_plan`: the PMUs, channels and encoded events a host would use, or
  why it cannot count.
- :mod:`~hdeem_watch.counters.reader`: the :class:`~hdeem_watch.counters.reader.CounterReader`
  protocol and a fake for tests.
- :mod:`~hdeem_watch.counters.arithmetic`: multiplexing scaling, counter-width wrap, window deltas.
- :mod:`~hdeem_watch.counters.command_mapping`: per-channel counter deltas → ``CommandStats``.
- :mod:`~hdeem_watch.counters.perf_counters`: the host's counters as a counter source.
- :mod:`~hdeem_watch.counters.setting`: the counter source of the daemon's ``counters`` setting.
- :mod:`~hdeem_watch.counters.perf_reader`: the real ``perf_event_open`` reader (ctypes).
- :mod:`~hdeem_watch.counters.source`: the counter-source port the daemon reads (cumulative role
  counts on the power samples' axis), window differences and interpolation.

See docs/counters.md.
"""
