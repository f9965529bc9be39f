"""Issue 11's lead for strongly coloured noise, measured: the break scan fits a line to each
side of a split on the *whitened* window, but a step J of the torque at sample k whitens to J at
k and (1 - phi) J after it, so at phi 0.85 most of the step's evidence is in that one sample,
which the two lines leave in their residuals. The GLS break regression whitens the step and the
step times angle as it whitens the window's line; it differs from the two-line fit only in the
p rows after the split (here AR(1): one row).

Both scans run here in numpy on the window tightscan itself tests (``tested_start_angle`` to
``tested_end_angle``, the recorded angle), whitened by AR(1) at tightscan's ``noise_lag1``, each
judged by a threshold matched to 1 % false alarms on clean curves of the same cell (one
threshold for every window length, the same treatment for both scans). Recall on changes of
15-45 % and 3-15 % that reached the window, beside the default rule at its own alpha. Not the
engine's scan (no Gaussianising, no weights, no staircase interpolation: on the built-in
simulator's 0.1 deg staircase the matched thresholds come out at 200-640 and the figures mean
little); a measurement of the lead, not of a detector.

    PYTHONPATH=tests .venv/bin/python benches/gls_lead.py [--n 600] [--generator independent] [--cell "ar1 0.85"]

Measured (2026-11-26, 600 clean + 600 faulty curves, independent generator): AR(1) 0.85 two
lines 63.9 / 26.8 %, GLS 83.7 / 61.1 %; AR(1) 0.5 93.5 / 75.5 -> 94.2 / 78.8 %; white noise
identical (at phi 0 the GLS regression is the two-line fit). The engine runs the GLS scan
since the fourteenth session (``detectors/gls_breakpoint.rs``); its numpy form here is
``bench_cusum.sup_lr``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import tightscan

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "benches"))
import bench_cusum  # noqa: E402
import detection_quality as dq  # noqa: E402


def _line_rss(s0: np.ndarray, s1: np.ndarray, s2: np.ndarray, t1: np.ndarray, t2: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Residual sum of squares of a line with intercept from the sums of 1, x, x^2, y, y^2, xy."""
    with np.errstate(divide="ignore", invalid="ignore"):
        sxx = s2 - s1**2 / s0
        sxy = q - s1 * t1 / s0
        return (t2 - t1**2 / s0) - sxy**2 / sxx


def scans(angle: np.ndarray, torque: np.ndarray, phi: float) -> tuple[float, float]:
    """sup-LR of the two-line scan and of the GLS break regression over every split with at
    least 5 % (and 10) whitened samples each side; NaN for a window too short."""
    x, y = angle - angle.mean(), torque - torque.mean()
    wy, wx = y[1:] - phi * y[:-1], x[1:] - phi * x[:-1]
    n = len(wy)
    trim = max(int(np.ceil(0.05 * n)), 10)
    if n < 2 * trim + 2:
        return float("nan"), float("nan")

    def cum(v: np.ndarray) -> np.ndarray:
        return np.concatenate([[0.0], np.cumsum(v)])

    p1, p2, pt, pt2, pq = cum(wx), cum(wx**2), cum(wy), cum(wy**2), cum(wx * wy)
    ks = np.arange(trim, n - trim + 1)
    left = _line_rss(ks.astype(float), p1[ks], p2[ks], pt[ks], pt2[ks], pq[ks])
    right = _line_rss((n - ks).astype(float), p1[n] - p1[ks], p2[n] - p2[ks], pt[n] - pt[ks], pt2[n] - pt2[ks], pq[n] - pq[ks])
    rss0 = float(_line_rss(np.array(float(n)), p1[n], p2[n], pt[n], pt2[n], pq[n]))
    with np.errstate(divide="ignore"):
        two_lines = float(np.max(n * np.log(rss0 / (left + right))))
    # GLS: the engine's scan as numpy (bench_cusum.sup_lr: columns 1, wx, the whitened step and
    # the whitened step x angle, normal equations from prefix sums).
    scan = bench_cusum.sup_lr(x, y, phi)
    gls = scan[0] if scan is not None else float("nan")
    return two_lines, gls


def statistics(generator: str, cell: dq.Cell, n: int, seed: int, faulty: bool) -> tuple[np.ndarray, object, object]:
    curves, truth = dq.generate(generator, cell, n, seed, faulty)
    results = tightscan.detect_batch(curves).to_pandas()
    angles, torques = curves["angle"].to_pylist(), curves["torque"].to_pylist()
    out = np.full((len(results), 2), np.nan)
    for i, row in enumerate(results.itertuples()):
        if row.status != "ok" or not np.isfinite(row.noise_lag1):
            continue
        a, y = np.asarray(angles[i], float), np.asarray(torques[i], float)
        inside = (a >= row.tested_start_angle) & (a <= row.tested_end_angle)
        out[i] = scans(a[inside], y[inside], float(np.clip(row.noise_lag1, 0.0, 0.99)))
    return out, results, truth


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=600, help="clean and faulty curves each")
    ap.add_argument("--generator", default="independent", choices=list(dq.GENERATORS))
    ap.add_argument("--cell", default="ar1 0.85", help=f"one of: {', '.join(c.name for c in dq.CELLS)}")
    args = ap.parse_args()
    cells = list(dq.CELLS)
    k = [i for i, c in enumerate(cells) if c.name == args.cell][0]
    seed = 20261126 + 1000 * list(dq.GENERATORS).index(args.generator) + 10 * k  # detection_quality's seeds
    clean, clean_results, _ = statistics(args.generator, cells[k], args.n, seed + 1, False)
    faulty, faulty_results, truth = statistics(args.generator, cells[k], args.n, seed + 2, True)
    decided = np.all(np.isfinite(faulty), axis=1)
    threshold = np.nanquantile(clean[np.all(np.isfinite(clean), axis=1)], 0.99, axis=0)
    reached = truth.true_onset_reached.astype(bool).to_numpy() & decided  # type: ignore[attr-defined]
    large = reached & (truth.true_magnitude.abs() >= 0.15).to_numpy()  # type: ignore[attr-defined]
    small = reached & (truth.true_magnitude.abs() < 0.15).to_numpy()  # type: ignore[attr-defined]
    print(f"{args.generator}, {args.cell}: {args.n} clean / {args.n} faulty curves, {int(large.sum())} large and {int(small.sum())} small changes reached")
    for name, j in (("two lines (engine before)", 0), ("GLS (the engine now)", 1)):
        hit = faulty[:, j] > threshold[j]
        print(f"  {name:26s} threshold {threshold[j]:7.2f}: recall 15-45 % {100 * hit[large].mean():5.1f}, 3-15 % {100 * hit[small].mean():5.1f}")
    rule = faulty_results.change_detected.fillna(False).astype(bool).to_numpy()  # type: ignore[attr-defined]
    fa = clean_results.change_detected.dropna().astype(bool).mean()  # type: ignore[attr-defined]
    print(f"  {'default rule (its alpha)':26s} FA {100 * fa:.2f} %: recall 15-45 % {100 * rule[large].mean():5.1f}, 3-15 % {100 * rule[small].mean():5.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
