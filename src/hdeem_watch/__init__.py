"""hdeem-watch: DRAM power monitoring and DRAM power-model calibration on HPC nodes.

Packages:
    dram: DDR4 memspecs, command traces, command statistics and DRAMPower-equivalent energy.
    calibrate: bounded least-squares IDD calibration, identifiability, online refits.
    sources: power sensors (HDEEM, RAPL DRAM, replay, simulated node).
    daemon: the node daemon (polling, ZeroMQ publishing, runs, baselines, SQLite state).
    bench: STREAM-like memory kernels and the run schedule that feeds the calibrator.
    tui: the Textual user interface.
"""

__version__ = "0.1.0"
