"""hdeem_watch.daemon."""
