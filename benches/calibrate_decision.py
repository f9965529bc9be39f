"""Remeasures the decision rule's calibration (detect.rs ``DECISION_CALIBRATION``).

For each internal alpha of the table, the false-alarm rate of the default rule (any of break and
cusum) on in-control simulated tightenings of all strategies with the simulator's defaults. The
rule is run with ``calibrated=False``, so the calibration itself is bypassed and the raw union-bound split is
measured.

    .venv/bin/python benches/calibrate_decision.py [--n 20000] [--seed 4242]
"""

from __future__ import annotations

import argparse

import numpy as np

import tightscan

INTERNAL_ALPHAS = (0.005, 0.01, 0.02, 0.05, 0.1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--n", type=int, default=20_000)
    parser.add_argument("--seed", type=int, default=4242)
    args = parser.parse_args()
    curves, _ = tightscan.simulate(args.n, seed=args.seed, fault_fraction=0.0)
    print("pub const DECISION_CALIBRATION: [(f64, f64); 5] =")
    rows = []
    for alpha in INTERNAL_ALPHAS:
        results = tightscan.detect_batch(curves, config={"alpha": alpha, "calibrated": False})
        rate = float(np.mean([bool(x) for x in results.column("change_detected").to_pylist()]))
        rows.append(f"({alpha}, {rate:.4f})")
    print("    [" + ", ".join(rows) + "];")


if __name__ == "__main__":
    main()
