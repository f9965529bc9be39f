"""How a Parquet scan scales from 1 to 2 workers on each engine, and what a task costs.

    python benches/engine_scaling.py [--files 24] [--per-file 400]

Writes ``--files`` Parquet files of ``--per-file`` simulated tightenings each, then scans the
directory into a results directory (one task per file) with: the local engine on 1 and 2
Rust threads, Dask (``LocalCluster``, 1 and 2 single-threaded worker processes) and Ray
(``num_cpus`` 1 and 2). Every worker runs the Rust engine on one thread
(``RAYON_NUM_THREADS=1``), so "2 workers" means two cores, as on a cluster of one-core
workers. Then the same scans over ``--files`` files of one tightening each: the wall time
per file there is the per-task overhead of each engine (scheduling, pickling the plan,
opening the file, the atomic rename, the manifest).

Prints tightenings/s per engine and worker count, the overhead in worker-ms per task, and
the smallest file (in tightenings) for which that overhead stays under 5 % of a task. The
figures mean something only on an otherwise idle machine (it prints the load average).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable

sys.path.insert(0, str(Path(__file__).resolve().parent))

os.environ["RAYON_NUM_THREADS"] = "1"  # before tightscan's Rust pool starts: one core per worker
os.environ.setdefault("RAY_AUTH_MODE", "disabled")

import pyarrow.parquet as pq  # noqa: E402

import tightscan  # noqa: E402
from _benchutil import cpu_busy  # noqa: E402


def write_files(root: Path, files: int, per_file: int, seed: int) -> None:
    root.mkdir(parents=True)
    curves, _ = tightscan.simulate(files * per_file, seed=seed)
    for i in range(files):
        pq.write_table(curves.slice(i * per_file, per_file), root / f"part-{i:03d}.parquet")


def seconds(scan: Callable[[], object], out: Path) -> float:
    shutil.rmtree(out, ignore_errors=True)
    t = time.perf_counter()
    scan()
    return time.perf_counter() - t


def local_seconds(src: Path, out: Path, threads: int) -> float:
    """The local engine in a fresh process: the Rust pool is sized once per process."""
    shutil.rmtree(out, ignore_errors=True)
    code = (
        "import sys, time, tightscan; t = time.perf_counter(); "
        "tightscan.scan_parquet(sys.argv[1], sys.argv[2], progress=False); print(time.perf_counter() - t)"
    )
    env = dict(os.environ, RAYON_NUM_THREADS=str(threads))
    done = subprocess.run([sys.executable, "-c", code, str(src), str(out)], env=env, check=True, capture_output=True, text=True)
    return float(done.stdout)


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    ap.add_argument("--files", type=int, default=24)
    ap.add_argument("--per-file", type=int, default=400)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--engines", nargs="+", default=["local", "dask", "ray"])
    args = ap.parse_args()
    busy = cpu_busy()
    print(f"CPUs: {os.cpu_count()}, busy before start: {busy:.0%}" if busy is not None else f"CPUs: {os.cpu_count()}")
    print(f"load average: {os.getloadavg()[0]:.1f}")
    work = Path(tempfile.mkdtemp(prefix="tightscan-scaling-"))
    big, tiny = work / "big", work / "tiny"
    write_files(big, args.files, args.per_file, args.seed)
    write_files(tiny, args.files, 1, args.seed)
    n_big = args.files * args.per_file
    rows: list[tuple[str, int, float, float]] = []  # engine, workers, tightenings/s, ms per tiny task

    def record(engine: str, workers: int, scan_seconds: Callable[[Path], float]) -> None:
        # best of two: the first run also warms the workers up
        t_big = min(scan_seconds(big) for _ in range(2))
        t_tiny = min(scan_seconds(tiny) for _ in range(2))
        # worker time per task: Dask and Ray run `workers` files at once, the local engine one
        # file at a time (its threads share the tightenings of a batch)
        ms = 1000 * t_tiny * (workers if engine != "local" else 1) / args.files
        rows.append((engine, workers, n_big / t_big, ms))
        print(f"{engine:6s} {workers} worker(s): {n_big / t_big:8.0f} tightenings/s, {ms:6.1f} ms per task", flush=True)

    out = work / "out"
    if "local" in args.engines:
        for n in (1, 2):
            record("local", n, lambda src: local_seconds(src, out, n))
    if "dask" in args.engines:
        from distributed import Client, LocalCluster

        for n in (1, 2):
            with LocalCluster(n_workers=n, threads_per_worker=1, dashboard_address=":0", processes=True) as cluster, Client(cluster):
                record("dask", n, lambda src: seconds(lambda: tightscan.scan_parquet(src, out, engine="dask", progress=False), out))
    if "ray" in args.engines:
        import ray

        for n in (1, 2):
            ray.init(num_cpus=n, include_dashboard=False, log_to_driver=False, runtime_env={"env_vars": {"RAYON_NUM_THREADS": "1"}})
            try:
                record("ray", n, lambda src: seconds(lambda: tightscan.scan_parquet(src, out, engine="ray", progress=False), out))
            finally:
                ray.shutdown()

    print(f"\n{args.files} files x {args.per_file} tightenings; per-task overhead from {args.files} files of 1 tightening")
    print(f"load average at the end: {os.getloadavg()[0]:.1f} (on {os.cpu_count()} CPUs: above that, workers wait for a core)")
    print(f"{'engine':8s}{'workers':>8s}{'tightenings/s':>15s}{'x 1 worker':>12s}{'ms/task':>9s}{'file for <5 % overhead':>24s}")
    one = {e: r for e, w, r, _ in rows if w == 1}
    for engine, workers, rate, ms in rows:
        per_worker = rate / workers
        # overhead / (overhead + n / per_worker) < 5 %  <=>  n > 19 * overhead * per_worker
        min_file = 19 * (ms / 1000) * per_worker
        print(f"{engine:8s}{workers:8d}{rate:15.0f}{rate / one[engine]:12.2f}{ms:9.1f}{min_file:20.0f} tightenings")
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
