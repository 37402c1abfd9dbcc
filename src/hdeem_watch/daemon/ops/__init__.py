"""The control operations: run, baseline, calibration, query and job ops over the run book and narrow ports."""
