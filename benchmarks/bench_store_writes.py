"""The acknowledged-write path of the state database: store worker → store → its one writer thread.

Times ``--writes`` run records (a 2 KB record each) handed to :class:`StoreWorker` until every
one is acknowledged as on disk (``done(True)``) and the writer's queue is empty; prints the median
of ``--repeats`` fresh databases.

    python3 benchmarks/bench_store_writes.py --writes 500 --repeats 5
"""

from __future__ import annotations

import argparse
import pathlib
import statistics
import tempfile
import time

from hdeem_watch.daemon.store.database import Store
from hdeem_watch.daemon.store.worker import StoreWorker


def one_round(writes: int) -> float:
    """Seconds for ``writes`` acknowledged run writes into a fresh database."""
    store = Store(pathlib.Path(tempfile.mkdtemp()) / "state.db")
    worker = StoreWorker(store)
    acknowledged: list[bool] = []
    start = time.perf_counter()
    for n in range(1, writes + 1):
        record = {"run_id": f"r{n}", "kernel": "triad", "state": "done", "t_start_ns": n, "pad": "x" * 2000}
        worker.write(f"run r{n}", lambda s, r=record: s.save_run(r), acknowledged.append)  # type: ignore[misc]
    worker.shutdown()
    worker.collect()
    store.flush()
    elapsed = time.perf_counter() - start
    store.close()
    if acknowledged != [True] * writes:
        raise SystemExit(f"only {sum(acknowledged)} of {writes} writes were acknowledged as stored")
    return elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--writes", type=int, default=500)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    times = [one_round(args.writes) for _ in range(args.repeats)]
    print(f"{args.writes} acknowledged run writes, median of {args.repeats}: {statistics.median(times):.3f} s "
          f"({', '.join(f'{t:.3f}' for t in times)})")


if __name__ == "__main__":
    main()
