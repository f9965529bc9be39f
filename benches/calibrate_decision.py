"""Remeasures the decision rule's calibration (engine/decision.rs ``DECISION_CALIBRATION``).

For each internal alpha of the table, the false-alarm rate of the default rule (any of break and
cusum) on in-control simulated tightenings of all strategies with the simulator's defaults. The
rule is run with ``calibrated=False``, so the calibration itself is bypassed and the raw union-bound split is
measured.

    .venv/bin/python benches/calibrate_decision.py [--n 100000] [--seed 4242] [--chunk 20000]
"""

from __future__ import annotations

import argparse

import numpy as np

import tightscan

INTERNAL_ALPHAS = (0.005, 0.01, 0.02, 0.05, 0.1, 0.2)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--n", type=int, default=100_000)
    parser.add_argument("--seed", type=int, default=4242)
    parser.add_argument("--chunk", type=int, default=20_000, help="tightenings simulated at once (memory)")
    args = parser.parse_args()
    alarms = np.zeros(len(INTERNAL_ALPHAS))
    for first in range(0, args.n, args.chunk):
        m = min(args.chunk, args.n - first)
        # Consecutive seeds per chunk: the same curves whatever the chunk size is not needed,
        # only that every run of the script with the same arguments sees the same data.
        curves, _ = tightscan.simulate(m, seed=args.seed + first, fault_fraction=0.0, first_id=first)
        for j, alpha in enumerate(INTERNAL_ALPHAS):
            # L1 is outside the rule and takes the whole alpha there, limited to its table (0.1).
            results = tightscan.detect_batch(curves, config={"alpha": alpha, "calibrated": False, "l1_alpha": 0.05})
            alarms[j] += sum(bool(x) for x in results.column("change_detected").to_pylist())
    print(f"// {args.n} clean tightenings, seed {args.seed}, chunks of {args.chunk}")
    print(f"pub const DECISION_CALIBRATION: [(f64, f64); {len(INTERNAL_ALPHAS)}] =")
    rows = [f"({alpha}, {alarms[j] / args.n:.4f})" for j, alpha in enumerate(INTERNAL_ALPHAS)]
    print("    [" + ", ".join(rows) + "];")


if __name__ == "__main__":
    main()
