"""Samples/s of `tightscan.detect_batch` (default rule) on one in-memory table: the first call
(cold: per-process caches such as the noise fit's residual weights are empty) and the best of
the next `--repeat` calls (warm). Run it once per thread count, each in its own process
(`RAYON_NUM_THREADS` fixes rayon's pool when the process starts), and alternate builds when
comparing two, so that both see the same load on a shared machine.

    RAYON_NUM_THREADS=1 PYTHONPATH=python python benches/detect_throughput.py --input curves.parquet

The input is a Parquet file of curves (e.g. compare_results.py's inputs/simulate.parquet, the
curves of `tightscan.simulate(3000, seed=7)`); prints one line: threads, samples, cold and warm
samples/s, and the 1-minute load average before the run.
"""

from __future__ import annotations

import argparse
import os
import time

import pyarrow.compute as pc
import pyarrow.parquet as pq

import tightscan


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--input", required=True)
    parser.add_argument("--repeat", type=int, default=2)
    args = parser.parse_args()
    table = pq.read_table(args.input)
    samples = int(pc.sum(pc.list_value_length(table["angle"])).as_py())
    load = os.getloadavg()[0]
    start = time.perf_counter()
    tightscan.detect_batch(table)
    cold = time.perf_counter() - start
    warm = float("inf")
    for _ in range(args.repeat):
        start = time.perf_counter()
        tightscan.detect_batch(table)
        warm = min(warm, time.perf_counter() - start)
    threads = os.environ.get("RAYON_NUM_THREADS", "all")
    print(f"threads {threads}: {samples} samples, cold {samples / cold / 1e6:.2f} M/s, warm {samples / warm / 1e6:.2f} M/s, load {load:.1f}")


if __name__ == "__main__":
    main()
