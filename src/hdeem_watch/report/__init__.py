"""Reports: the paper's figures from a daemon state or a RUNS.json (see docs/report.md)."""
