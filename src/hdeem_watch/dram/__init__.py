"""hdeem_watch.dram."""
