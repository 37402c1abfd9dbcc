"""hdeem_watch.tui."""
