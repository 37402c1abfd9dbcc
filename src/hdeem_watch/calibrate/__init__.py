"""hdeem_watch.calibrate."""
