"""Write runs.json (a RUNS.json for ``hdeem-watch calibrate`` and ``report --runs``) from a daemon state.

Every finished idle run and every run at 24 threads of the state becomes one RUNS.json run: its
measured node DRAM energy and window, and the command statistics of one DIMM of the run as the
daemon modelled it (at 24 threads both sockets carry the same traffic, so one ``stats`` with
``scale`` = 8 DIMMs is the whole node).

Usage: ``PYTHONPATH=src python3 tests/report/data/make_runs_json.py STATE.db OUT.json``
"""

from __future__ import annotations

import json
import sqlite3
import sys

from hdeem_watch.dram.memspec import preset
from hdeem_watch.dram.node import idle_channel_stats, node_run_stats, topology_for

PRESET = "samsung-m393a1g43db0-cpb"


def main(state: str, out: str) -> None:
    spec = preset(PRESET)
    db = sqlite3.connect(f"file:{state}?mode=ro", uri=True)
    runs = []
    for (text,) in db.execute("SELECT record FROM runs ORDER BY seq"):
        record = json.loads(text)
        if record["state"] != "done" or not (record["kernel"] == "idle" or record["threads"] == 24):
            continue
        dimms = record["model"]["dimms"]
        if record["kernel"] == "idle":
            stats = idle_channel_stats(spec)
        else:
            groups = node_run_stats(spec, record["kernel"], record["elements"], record["threads"], record["repeat"],
                                    topology_for(dimms))
            assert groups[0][0] == groups[1][0], "24 threads load both sockets alike"
            stats = groups[0][0]
        runs.append({"name": record["name"], "measured_j": record["dram_energy_j"], "stats": stats.to_dict(),
                     "scale": dimms, "window_s": record["window_s"], "time_ns": record["t_stop_ns"]})
    with open(out, "w", encoding="utf-8") as file:
        json.dump({"memspec": f"preset:{PRESET}", "runs": runs}, file, indent=1)
        file.write("\n")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
