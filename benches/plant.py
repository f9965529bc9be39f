#!/usr/bin/env python3
"""A plant's worth of tightenings end to end: ``tightscan simulate`` to Parquet, then
``tightscan scan`` of that file, each as a command a user would type, in a process of its own.

For each step: wall time, samples/s and peak RSS (the child's own ``ru_maxrss`` from
``os.wait4``, so one step's memory does not hide in another's), and for the scan the time
pyarrow alone needs to read the same file (``ParquetFile.iter_batches``, in its own process)
as the yardstick of "scans at Parquet read speed". Not in CI: a million tightenings are about
10^9 samples, 17 GB of Parquet and tens of minutes on two cores.

Usage::

    python benches/plant.py                       # 1,000,000 tightenings (check `df -h` first)
    python benches/plant.py --n 100000 --dir /big/disk/tmp
    python benches/plant.py --n 20000 --json benches/results/plant-20k.json

The data are deleted afterwards unless ``--keep``. Figures go to stdout and to ``--json``
(default ``benches/results/plant-<n>.json``, which ``benches/perf_table.py`` reads).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"

# pyarrow alone reading a file as the scan's reader does, batch by batch, all columns.
READ_ONLY = """
import sys, pyarrow.parquet as pq
f = pq.ParquetFile(sys.argv[1], buffer_size=1 << 20, pre_buffer=False)
rows = 0
for batch in f.iter_batches(batch_size=int(sys.argv[2])):
    rows += batch.num_rows
print(rows)
"""


def run_measured(argv: list[str], env: dict[str, str] | None = None) -> dict[str, Any]:
    """Runs ``argv`` to its end; wall seconds, the child's peak RSS [MB] and its CPU seconds."""
    started = time.perf_counter()
    child = subprocess.Popen(argv, stdout=subprocess.PIPE, env=env)
    assert child.stdout is not None
    out = child.stdout.read()
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.perf_counter() - started
    child.returncode = os.waitstatus_to_exitcode(status)
    if child.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed with exit code {child.returncode}")
    return {
        "seconds": wall,
        "peak_rss_mb": usage.ru_maxrss / 1024,
        "cpu_seconds": usage.ru_utime + usage.ru_stime,
        "stdout": out.decode(),
    }


def plant(n: int, workdir: Path, seed: int = 1, keep: bool = False) -> dict[str, Any]:
    """Simulates ``n`` tightenings into ``workdir`` and scans them; the figures of both steps."""
    workdir.mkdir(parents=True, exist_ok=True)
    curves = workdir / f"plant-{n}.parquet"
    results = workdir / f"plant-{n}-results.parquet"
    tightscan = [sys.executable, "-m", "tightscan"]
    try:
        sim = run_measured([*tightscan, "simulate", "-n", str(n), "--seed", str(seed), "-o", str(curves), "--json", "-q"])
        sim_json = json.loads(sim.pop("stdout"))
        samples = int(sim_json["samples"])
        file_bytes = curves.stat().st_size
        scan = run_measured([*tightscan, "scan", str(curves), "-o", str(results), "--json", "-q"])
        scan_json = json.loads(scan.pop("stdout"))
        # the same batches the scan reads (its default: ~16 MB decoded per batch)
        sys.path.insert(0, str(HERE.parent / "python"))
        rows_per_batch = _scan_batch_rows(curves)
        read = run_measured([sys.executable, "-c", READ_ONLY, str(curves), str(rows_per_batch)])
        read.pop("stdout")
    finally:
        if not keep:
            for path in (curves, results, curves.with_name(curves.stem + "-truth.parquet")):
                path.unlink(missing_ok=True)
    return {
        "n": n,
        "samples": samples,
        "parquet_bytes": file_bytes,
        "simulate": {**sim, "samples_per_s": samples / sim["seconds"]},
        "scan": {
            **scan,
            "samples_per_s": samples / scan["seconds"],
            "tightenings": scan_json["tightenings"],
            "changes": scan_json["changes"],
        },
        "read": {**read, "samples_per_s": samples / read["seconds"], "batch_rows": rows_per_batch},
        "scan_over_read": scan["seconds"] / read["seconds"],
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "load_at_end": os.getloadavg()},
        "commit": _commit(),
        "timestamp": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


def _commit() -> str | None:
    """The code measured (uncommitted changes are marked)."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=HERE, capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "python", "crates"], cwd=HERE, capture_output=True, text=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None
    return head + ("+changes" if dirty else "")


def _scan_batch_rows(path: Path) -> int:
    import pyarrow.parquet as pq

    from tightscan._scan import BATCH_BYTES

    meta = pq.read_metadata(path)
    widest = max(meta.row_group(i).total_byte_size / meta.row_group(i).num_rows for i in range(meta.num_row_groups))
    return max(1, int(BATCH_BYTES // widest))


def print_figures(fig: dict[str, Any]) -> None:
    print(f"plant of {fig['n']:,} tightenings, {fig['samples']:,} samples, {fig['parquet_bytes'] / 1e9:.2f} GB of Parquet")
    print(f"{'step':<10} {'wall s':>9} {'M samples/s':>12} {'peak RSS MB':>12} {'CPU s':>9}")
    for step in ("simulate", "scan", "read"):
        s = fig[step]
        print(f"{step:<10} {s['seconds']:>9.1f} {s['samples_per_s'] / 1e6:>12.2f} {s['peak_rss_mb']:>12.0f} {s['cpu_seconds']:>9.1f}")
    print(f"scan / pyarrow read: {fig['scan_over_read']:.1f}x (load average at the end {fig['machine']['load_at_end'][0]:.1f})")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=1_000_000, help="tightenings (default 1,000,000: ~17 GB of Parquet)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--dir", type=Path, default=None, help="where the data go (default: a temporary directory)")
    ap.add_argument("--keep", action="store_true", help="keep the Parquet files")
    ap.add_argument("--json", type=Path, default=None, help="output (default benches/results/plant-<n>.json)")
    args = ap.parse_args()
    workdir = args.dir or Path(tempfile.mkdtemp(prefix="tightscan-plant-"))
    need = args.n * 18_000
    free = shutil.disk_usage(workdir if workdir.exists() else workdir.parent).free
    if free < need * 1.1:
        raise SystemExit(f"{args.n:,} tightenings need about {need / 1e9:.1f} GB; {workdir} has {free / 1e9:.1f} GB free")
    fig = plant(args.n, workdir, args.seed, args.keep)
    if args.dir is None and not args.keep:
        shutil.rmtree(workdir, ignore_errors=True)
    print_figures(fig)
    out = args.json or RESULTS / f"plant-{args.n}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(fig, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
