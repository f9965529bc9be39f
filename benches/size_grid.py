"""False-alarm rate of the default decision rule over a grid of noise colours, sampling rates,
encoder steps and strategies, on both generators: the built-in simulator (its noise replaced by
the grid's) and the independent generator of the tests (tests/independent_generator, written
from the physics texts without the simulator's code).

Every cell is clean curves only; the rule runs at alpha (default 0.01) as a user would run it.
A cell passes when its rate lies within [0.5, 1.5] x alpha (the detection-validity issue's
goal). Prints each cell's rate with each detector of the rule's own rate beside it, then a
table of those detectors' rates pooled by generator, noise and sampling rate against their shares
of alpha (where a cell's excess or shortfall comes from), and writes
benches/results/size_grid.json.

    .venv/bin/python benches/size_grid.py [--n 1000] [--alpha 0.01] [--quick]
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

import tightscan

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
import independent_generator as ig  # noqa: E402
from scoring import wilson  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"

# (label, colour, phi)
NOISES = [("white", "white", 0.0), ("ar1 0.5", "ar1", 0.5), ("ar1 0.85", "ar1", 0.85), ("ar1 0.9", "ar1", 0.9), ("t4", "t4", 0.0)]
RATES = [500.0, 2000.0, 10000.0]
ENCODERS = [0.01, 0.1, 0.5]
STRATEGIES = ["CST", "CSDT", "HDT"]


def unit_noise(rng: np.random.Generator, n: int, colour: str, phi: float) -> np.ndarray:
    """Unit-variance noise of the colour asked for (the same marginal sd whatever phi)."""
    if colour == "t4":
        return rng.standard_t(4, size=n) / math.sqrt(2.0)  # t4 has variance 2
    e = np.empty(n)
    innovations = rng.normal(size=n) * math.sqrt(1.0 - phi * phi)
    e[0] = rng.normal()
    for i in range(1, n):
        e[i] = phi * e[i - 1] + innovations[i]
    return e


def builtin_cell(n: int, seed: int, strategy: str, rate: float, encoder: float, colour: str, phi: float) -> pa.Table:
    """Built-in simulator, noise-free, then the grid's noise at its default level (0.2 % of target)."""
    curves, _ = tightscan.simulate(
        n, seed=seed, fault_fraction=0.0, strategies=[strategy], torque_noise=0.0, sample_rate_hz=rate, angle_resolution_deg=encoder
    )
    rng = np.random.default_rng(seed)
    noisy = [
        np.asarray(t, dtype=float) + 0.002 * target * unit_noise(rng, len(t), colour, phi)
        for t, target in zip(curves["torque"].to_pylist(), curves["target_torque"].to_pylist())
    ]
    return curves.set_column(curves.column_names.index("torque"), "torque", pa.array(noisy, pa.list_(pa.float64())))


def independent_cell(n: int, seed: int, strategy: str, rate: float, encoder: float, colour: str, phi: float) -> pa.Table:
    config = ig.GeneratorConfig(
        n=n, seed=seed, strategy=strategy, sample_rate_hz=rate, encoder_step_deg=encoder, noise=ig.NoiseConfig(colour=colour, phi=phi)
    )
    curves, _ = ig.generate(config)
    return curves


def run(generator: str, n: int, alpha: float, grid: list[tuple[Any, ...]]) -> list[dict[str, Any]]:
    make = builtin_cell if generator == "built-in simulator" else independent_cell
    rows = []
    for k, (strategy, rate, encoder, (label, colour, phi)) in enumerate(grid):
        t0 = time.perf_counter()
        curves = make(n, 1000 + k, strategy, rate, encoder, colour, phi)
        results = tightscan.detect_batch(curves, config={"alpha": alpha})
        detected = results["change_detected"].to_pylist()
        decided = [v for v in detected if v is not None]
        alarms = sum(bool(v) for v in decided)
        rate_ = alarms / len(decided) if decided else math.nan
        lo, hi = wilson(alarms, len(decided))
        # Each detector of the rule on its own, against its share of alpha: which one a cell's
        # excess or shortfall comes from.
        shares = tightscan.results_metadata(results)["shares"]
        fired = {name: 0 for name in shares}
        for names, v in zip(results["detectors_fired"].to_pylist(), detected):
            for name in (names or "").split(",") if v is not None else ():
                if name in fired:
                    fired[name] += 1
        rows.append(
            {
                "generator": generator, "strategy": strategy, "sample_rate_hz": rate, "encoder_deg": encoder, "noise": label,
                "curves": n, "decided": len(decided), "false_alarms": alarms, "rate": rate_, "ci95": [lo, hi],
                "within_goal": bool(0.5 * alpha <= rate_ <= 1.5 * alpha), "fired": fired, "shares": shares,
                "seconds": time.perf_counter() - t0,
            }
        )
        r = rows[-1]
        by_detector = " ".join(f"{name} {100 * k / max(1, len(decided)):.2f}" for name, k in fired.items())
        print(
            f"{generator:20s} {strategy:5s} {rate:7.0f} Hz {encoder:5.2f} deg {label:9s} decided {r['decided']:5d} "
            f"FAR {100 * rate_:6.2f} % [{100 * lo:5.2f}, {100 * hi:5.2f}] {'ok' if r['within_goal'] else 'MISS'}  {by_detector}",
            flush=True,
        )
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n", type=int, default=1000, help="clean curves per cell (the goal asks for 4,000)")
    parser.add_argument("--alpha", type=float, default=0.01)
    parser.add_argument("--quick", action="store_true", help="2 kHz and 0.1 deg only: noise x strategy")
    parser.add_argument(
        "--rates-encoders", action="store_true",
        help="CST, CSDT and HDT x 500 Hz / 2 kHz / 10 kHz x 0.01 / 0.1 / 0.5 deg: the independent generator with white "
        "and AR(1) 0.85 noise, the built-in simulator with white noise, seed 2000 for every cell (benches/README.md's "
        "rates x encoders table; --n 300 there)",
    )
    args = parser.parse_args()
    if args.rates_encoders:
        print("| strategy | rate | encoder | independent, white | independent, AR(1) 0.85 | built-in, white |")
        print("|---|---|---|---|---|---|")
        for strategy, rate, encoder in itertools.product(STRATEGIES, RATES, ENCODERS):
            cells = []
            for make, colour, phi in ((independent_cell, "white", 0.0), (independent_cell, "ar1", 0.85), (builtin_cell, "white", 0.0)):
                results = tightscan.detect_batch(make(args.n, 2000, strategy, rate, encoder, colour, phi), config={"alpha": args.alpha})
                decided = [v for v in results["change_detected"].to_pylist() if v is not None]
                cells.append(f"{100 * sum(decided) / max(1, len(decided)):.1f}% ({len(decided)})")
            print(f"| {strategy} | {rate:.0f} Hz | {encoder:g} deg | {' | '.join(cells)} |", flush=True)
        return 0
    rates, encoders = ([2000.0], [0.1]) if args.quick else (RATES, ENCODERS)
    grid = list(itertools.product(STRATEGIES, rates, encoders, NOISES))
    rows = run("built-in simulator", args.n, args.alpha, grid) + run("independent generator", args.n, args.alpha, grid)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "size_grid.json").write_text(json.dumps(rows, indent=1))
    for generator in ("built-in simulator", "independent generator"):
        mine = [r for r in rows if r["generator"] == generator]
        decided = sum(r["decided"] for r in mine)
        alarms = sum(r["false_alarms"] for r in mine)
        print(
            f"{generator}: {sum(r['within_goal'] for r in mine)} of {len(mine)} cells within [0.5, 1.5] x alpha; "
            f"pooled {100 * alarms / max(decided, 1):.2f} %"
        )
    print()
    print(detector_table(rows))
    return 0


def detector_table(rows: list[dict[str, Any]]) -> str:
    """Markdown: each detector of the rule's false-alarm rate (%) pooled over the cells of one
    generator, noise and sampling rate, against its share of alpha (the union bound's budget)."""
    names = list(rows[0]["shares"]) if rows else []
    shares = rows[0]["shares"] if rows else {}
    head = " | ".join(f"{name} (share {100 * shares[name]:.2f})" for name in names)
    lines = [f"| generator | noise | rate | {head} | rule |", "|---|---|---|" + "---|" * (len(names) + 1)]
    keys = dict.fromkeys((r["generator"], r["noise"], r["sample_rate_hz"]) for r in rows)
    for generator, noise, rate in keys:
        cells = [r for r in rows if (r["generator"], r["noise"], r["sample_rate_hz"]) == (generator, noise, rate)]
        decided = max(1, sum(r["decided"] for r in cells))
        rates = " | ".join(f"{100 * sum(r['fired'][name] for r in cells) / decided:.2f}" for name in names)
        rule = 100 * sum(r["false_alarms"] for r in cells) / decided
        lines.append(f"| {generator} | {noise} | {rate:.0f} Hz | {rates} | {rule:.2f} |")
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
