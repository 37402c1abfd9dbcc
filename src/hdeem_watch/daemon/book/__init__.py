"""The run book: pure state of the node (channel accounts, windows, runs, baselines); no I/O, no threads."""
