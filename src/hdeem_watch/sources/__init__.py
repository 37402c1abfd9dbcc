"""hdeem_watch.sources."""
