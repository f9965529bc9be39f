"""Checks that a change to the engine left `detect_batch`'s results as they were.

Optimisations must not change a result. This script runs `tightscan.detect_batch` (the default
rule) on fixed inputs and compares every result column with a reference table written before
the change: floats equal within a relative tolerance (1e-9 by default; NaN equals NaN), every
other column (statuses, booleans, integers, strings) identical.

The inputs, each written once to ``<dir>/inputs/<name>.parquet`` so that later runs detect on
exactly the same curves:

- ``simulate``: the curves of ``tightscan.simulate(3000, seed=7)``;
- ``ig_ar1``, ``ig_t4``, ``ig_encoder``: the independent generator (tests/independent_generator),
  300 tightenings each, AR(1) noise of phi 0.85, Student t4 noise, and a 0.5 deg encoder; the
  ``ig_faulty`` set adds abrupt/incipient/intermittent friction faults to half of 300 curves;
- ``rexroth``: the first 300 real runs of /work/shared/data/rexroth-s01/runs (skipped when the
  data is not there).

Usage (from the repository, with the extension built from the code to check)::

    PYTHONPATH=python:tests python benches/compare_results.py dump      # before the change
    PYTHONPATH=python:tests python benches/compare_results.py compare   # after it

``--dir`` (default /tmp/perfrs-ref) holds inputs and references; ``--rtol`` the tolerance.
Exits 1 on any difference, naming the data set, column and first differing rows.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import Callable

import pyarrow as pa
import pyarrow.parquet as pq

import tightscan

REXROTH_RUNS = Path("/work/shared/data/rexroth-s01/runs")
N_REXROTH = 300


def _independent(**kwargs: object) -> pa.Table:
    import independent_generator as ig

    noise = kwargs.pop("noise", None)
    fault = kwargs.pop("fault", None)
    config = ig.GeneratorConfig(
        n=300,
        noise=noise if noise is not None else ig.NoiseConfig(),
        fault=fault if fault is not None else ig.FaultConfig(),
        **kwargs,  # type: ignore[arg-type]
    )
    curves, _ = ig.generate(config)
    return curves


def _inputs() -> dict[str, Callable[[], pa.Table]]:
    import independent_generator as ig

    sets: dict[str, Callable[[], pa.Table]] = {
        "simulate": lambda: tightscan.simulate(3000, seed=7)[0],
        "ig_ar1": lambda: _independent(seed=101, noise=ig.NoiseConfig(colour="ar1", phi=0.85)),
        "ig_t4": lambda: _independent(seed=102, noise=ig.NoiseConfig(colour="t4")),
        "ig_encoder": lambda: _independent(seed=103, encoder_step_deg=0.5),
        "ig_faulty": lambda: _independent(
            seed=104, fault=ig.FaultConfig(kind="mix", magnitude=(0.05, 0.4), fraction_faulty=0.5)
        ),
    }
    if REXROTH_RUNS.is_dir():
        files = sorted(REXROTH_RUNS.glob("*.json"))[:N_REXROTH]
        sets["rexroth"] = lambda: tightscan.read_rexroth([str(f) for f in files])
    return sets


def _input(directory: Path, name: str, make: Callable[[], pa.Table]) -> pa.Table:
    path = directory / "inputs" / f"{name}.parquet"
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(make(), path)
    return pq.read_table(path)


def _samples(table: pa.Table) -> int:
    return int(sum(pa.compute.list_value_length(table["angle"]).fill_null(0).to_pylist()))


def _differences(name: str, ref: pa.Table, new: pa.Table, rtol: float) -> list[str]:
    problems = []
    if ref.schema != new.schema:
        # Columns added (a new detector's) are reported, and the columns both have compared.
        added = [c for c in new.column_names if c not in ref.column_names]
        kept = [c for c in new.column_names if c in ref.column_names]
        if kept != ref.column_names or any(ref.schema.field(c).type != new.schema.field(c).type for c in kept):
            return [f"{name}: schema differs:\n{ref.schema}\n---\n{new.schema}"]
        problems.append(f"{name}: columns added: {', '.join(added)}")
        new = new.select(kept)
    if ref.num_rows != new.num_rows:
        return [f"{name}: {ref.num_rows} rows before, {new.num_rows} now"]
    for column in ref.column_names:
        a, b = ref[column].to_pylist(), new[column].to_pylist()
        floating = pa.types.is_floating(ref.schema.field(column).type)
        bad = []
        for i, (x, y) in enumerate(zip(a, b)):
            if floating and x is not None and y is not None:
                same = (math.isnan(x) and math.isnan(y)) or x == y or abs(x - y) <= rtol * max(abs(x), abs(y))
            else:
                same = x == y
            if not same:
                bad.append(i)
        if bad:
            shown = ", ".join(f"row {i}: {a[i]!r} -> {b[i]!r}" for i in bad[:5])
            problems.append(f"{name}.{column}: {len(bad)} of {len(a)} rows differ ({shown})")
    return problems


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("mode", choices=["dump", "compare"])
    parser.add_argument("--dir", type=Path, default=Path("/tmp/perfrs-ref"))
    parser.add_argument("--rtol", type=float, default=1e-9)
    parser.add_argument("--only", nargs="*", help="data sets to run (default: all)")
    args = parser.parse_args()
    problems: list[str] = []
    for name, make in _inputs().items():
        if args.only and name not in args.only:
            continue
        table = _input(args.dir, name, make)
        start = time.perf_counter()
        results = tightscan.detect_batch(table)
        seconds = time.perf_counter() - start
        print(f"{name}: {table.num_rows} tightenings, {_samples(table)} samples, detect {seconds:.2f} s")
        ref_path = args.dir / "results" / f"{name}.parquet"
        if args.mode == "dump":
            ref_path.parent.mkdir(parents=True, exist_ok=True)
            pq.write_table(results, ref_path)
        else:
            problems += _differences(name, pq.read_table(ref_path), results, args.rtol)
    for p in problems:
        print(p)
    if args.mode == "compare":
        print("results identical" if not problems else f"{len(problems)} columns differ")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
