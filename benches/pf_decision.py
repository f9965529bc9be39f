"""Does the particle-filter test (``pf``) add recall to the default decision rule at an equal
false-alarm rate (issue 16's condition for it to join the rule)? On the cells of
benches/detection_quality.py (both generators, 2 kHz / 0.1 deg, noise white and AR(1) 0.85; its
``generate``: all strategies and fault kinds, |change| 3-45 %), for each configuration the
false-alarm rate on a clean set and the recall on a faulty set, over a grid of alpha:

- ``rule``: the default rule (break, cusum) at alpha;
- ``rule+pf``: the rule with pf as a third detector (alpha split three ways, the union bound);
- ``pf``: the pf test alone at pf_alpha = alpha.

The recall of each at the false-alarm rate ``--fa`` (default 1 %) is read off its (FA, recall)
points, linearly between the two that bracket it (log FA). Writes benches/results/pf_decision.json.

    .venv/bin/python benches/pf_decision.py [--n 300] [--fa 0.01]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

import tightscan

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import detection_quality as dq  # noqa: E402

ALPHAS = (0.002, 0.005, 0.01, 0.02, 0.05)
CONFIGS = {
    "rule": lambda a: {"alpha": a},
    "rule+pf": lambda a: {"alpha": a, "pf": True, "detectors": ["break", "cusum", "pf"]},
    "pf": lambda a: {"pf": True, "pf_alpha": a},
}
BANDS = ((0.03, 0.15), (0.15, 0.45))


def flags(curves: Any, config: dict[str, Any], name: str) -> np.ndarray:
    r = tightscan.detect_batch(curves, config=config)
    column = "pf_alarm" if name == "pf" else "change_detected"
    return np.array([bool(v) for v in r[column].to_pylist()])


def at_fa(points: list[tuple[float, list[float]]], fa: float) -> list[float]:
    """Recall per band at false-alarm rate ``fa``, between the bracketing points (log FA)."""
    pts = sorted(points)
    for (f0, r0), (f1, r1) in zip(pts, pts[1:]):
        if f0 <= fa <= f1:
            if f1 == f0:
                return r1
            w = (math.log(max(fa, 1e-4)) - math.log(max(f0, 1e-4))) / (math.log(max(f1, 1e-4)) - math.log(max(f0, 1e-4)))
            return [a + w * (b - a) for a, b in zip(r0, r1)]
    return [math.nan] * len(BANDS)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n", type=int, default=300)
    parser.add_argument("--fa", type=float, default=0.01)
    args = parser.parse_args()
    rows = []
    cells = [c for c in dq.CELLS if c.name in ("white", "ar1 0.85")]
    for g, generator in enumerate(("built-in", "independent")):
        for k, cell in enumerate(cells):
            seed = 31000 + 1000 * g + 10 * k
            clean, _ = dq.generate(generator, cell, args.n, seed + 1, faulty=False)
            faulty, truth = dq.generate(generator, cell, args.n, seed + 2, faulty=True)
            reached = truth["true_onset_reached"].to_numpy(bool)
            size = np.abs(truth["true_magnitude"].to_numpy(float))
            band = [reached & (size >= lo) & (size < hi) for lo, hi in BANDS]
            out: dict[str, Any] = {"generator": generator, "cell": cell.name, "n": args.n, "points": {}}
            for name, make in CONFIGS.items():
                pts = []
                for a in ALPHAS:
                    fa = float(flags(clean, make(a), name).mean())
                    hit = flags(faulty, make(a), name)
                    pts.append((fa, [float(hit[b].mean()) for b in band]))
                out["points"][name] = pts
                out[f"{name}_at_fa"] = at_fa(pts, args.fa)
                print(f"{generator:11s} {cell.name:8s} {name:8s} " + "  ".join(f"a {a}: FA {100 * f:.1f} % recall {100 * r[0]:.1f} / {100 * r[1]:.1f}"
                                                                          for a, (f, r) in zip(ALPHAS, pts)), flush=True)
            print(f"{generator:11s} {cell.name:8s} at FA {100 * args.fa:.1f} %: recall 3-15 / 15-45 % (reached: {int(band[0].sum())} / {int(band[1].sum())}) "
                  + "  ".join(f"{nm} {100 * out[f'{nm}_at_fa'][0]:.1f} / {100 * out[f'{nm}_at_fa'][1]:.1f}" for nm in CONFIGS), flush=True)
            rows.append(out)
    results = Path(__file__).resolve().parent / "results"
    results.mkdir(exist_ok=True)
    (results / "pf_decision.json").write_text(json.dumps({"fa": args.fa, "alphas": ALPHAS, "cells": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
