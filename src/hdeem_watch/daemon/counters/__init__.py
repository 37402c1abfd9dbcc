"""The daemon's memory-controller counters: the feed beside the poll loop, the record, per-window counts."""
