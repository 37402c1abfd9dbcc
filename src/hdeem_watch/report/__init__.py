"""Reports: the paper's figures for your own node, from a daemon state or a RUNS.json (docs/report.md).

Modules, one concept each:

- :mod:`~hdeem_watch.report.records`: the frozen records every figure is drawn from (``ReportData``);
- :mod:`~hdeem_watch.report.state_reader` / :mod:`~hdeem_watch.report.runs_reader`: the daemon's SQLite
  state (read-only) / a RUNS.json, into ``ReportData``;
- :mod:`~hdeem_watch.report.analysis`: pure numerics (groups, drift alarms, components, ``--since``);
- :mod:`~hdeem_watch.report.style`: matplotlib (imported only here, Agg), palette, markers, hatches;
- :mod:`~hdeem_watch.report.figure`, :mod:`~hdeem_watch.report.figures_model`,
  :mod:`~hdeem_watch.report.figures_time`: the figures and their tables;
- :mod:`~hdeem_watch.report.page`: the self-contained HTML page;
- :mod:`~hdeem_watch.report.build`: draws everything and writes the files;
- :mod:`~hdeem_watch.report.demo`: the report at the end of ``hdeem-watch demo --report``.

Nothing here is imported by the daemon; matplotlib is the optional ``report`` extra.
"""
