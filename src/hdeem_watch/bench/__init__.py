"""hdeem_watch.bench."""
