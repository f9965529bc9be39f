"""Share of the break scan's null alarms that pass its encoder-step check, by the check's jump
in units of the jump's null standard deviation: the Monte Carlo behind `SCAN_CHECK_PASSING`
(crates/tightscan-core/src/engine/analysis/breaks.rs).

The scan (two lines against one, likelihood ratio over every split with segments of at least
5 % of the window and 10 samples) runs on lines with white or AR(1) noise; its statistic is
taken on the whitened window (the GLS scan's), its jump between the recorded samples' two lines
at the split (as the engine reports it). Of the windows whose statistic is beyond its 1 % or
0.3 % point, the share whose |jump| exceeds t times 4 sigma_lr / sqrt(n) (sigma_lr the noise's
long-run sd, 4 / sqrt(n) the sd of the jump at the middle split of two lines) is printed for
t = 1..16. The shipped table is the upper envelope of the white-noise rows: coloured noise
passes less, so the share the engine hands to the CUSUM is never more than the scan leaves.

    python benches/scan_check_share.py [--reps 40000] [--seed 7]
"""
from __future__ import annotations

import argparse

import numpy as np

STEPS = (1, 2, 3, 4, 5, 6, 7, 8, 10, 12, 14, 16)


def _prefix(v: np.ndarray) -> np.ndarray:
    return np.concatenate([np.zeros((v.shape[0], 1)), np.cumsum(v, axis=1)], axis=1)


def scan(noise: np.ndarray, x: np.ndarray, phi: float) -> tuple[np.ndarray, np.ndarray]:
    """sup-LR statistic (whitened window) and the jump at its split (recorded samples)."""
    reps, n = noise.shape
    if phi:
        yw, xw, c = noise[:, 1:] - phi * noise[:, :-1], x[1:] - phi * x[:-1], 1.0 - phi
    else:
        yw, xw, c = noise, x, 1.0
    nw = yw.shape[1]
    s11 = np.r_[0, np.cumsum(np.full(nw, c * c))]
    s1x, sxx = np.r_[0, np.cumsum(c * xw)], np.r_[0, np.cumsum(xw * xw)]
    s1y, sxy, syy = _prefix(c * yw), _prefix(yw * xw), _prefix(yw * yw)

    def rss(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        g11, g1x, gxx = s11[b] - s11[a], s1x[b] - s1x[a], sxx[b] - sxx[a]
        g1y, gxy, gyy = s1y[:, b] - s1y[:, a], sxy[:, b] - sxy[:, a], syy[:, b] - syy[:, a]
        det = g11 * gxx - g1x * g1x
        b0, b1 = (gxx * g1y - g1x * gxy) / det, (g11 * gxy - g1x * g1y) / det
        return gyy - b0 * g1y - b1 * gxy

    m = max(int(np.ceil(0.05 * nw)), 10)
    ks = np.arange(m, nw - m + 1)
    whole = rss(np.array([0]), np.array([nw]))
    lr = nw * np.log(whole / (rss(np.zeros_like(ks), ks) + rss(ks, np.full_like(ks, nw))))
    best = np.argmax(lr, axis=1)
    statistic = lr[np.arange(reps), best]
    jump = np.empty(reps)
    for r, k in enumerate(ks[best] + (1 if phi else 0)):
        left, right = np.polyfit(x[:k], noise[r, :k], 1), np.polyfit(x[k:], noise[r, k:], 1)
        jump[r] = np.polyval(right, x[k]) - np.polyval(left, x[k])
    return statistic, jump


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--reps", type=int, default=40000)
    ap.add_argument("--seed", type=int, default=7)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    print("noise        n     alarm  " + " ".join(f"{t:>5}" for t in STEPS))
    for phi in (0.0, 0.85):
        for n in (250, 1000):
            x = np.arange(n) / n
            reps = args.reps if n <= 250 else max(args.reps * 3 // 10, 2000)
            stats, jumps = [], []
            for _ in range(max(reps // 2000, 1)):
                if phi:
                    e = rng.standard_normal((2000, n + 200))
                    y = np.empty_like(e)
                    y[:, 0] = e[:, 0] / np.sqrt(1 - phi**2)
                    for t in range(1, e.shape[1]):
                        y[:, t] = phi * y[:, t - 1] + e[:, t]
                    y = y[:, 200:]
                else:
                    y = rng.standard_normal((2000, n))
                st, j = scan(y, x, phi)
                stats.append(st)
                jumps.append(j)
            statistic, jump = np.concatenate(stats), np.concatenate(jumps)
            # Long-run sd of the noise (innovations of sd 1): 1 / (1 - phi).
            jump_sd = 4.0 / np.sqrt(n) / (1.0 - phi)
            for q in (0.01, 0.003):
                alarm = statistic > np.quantile(statistic, 1 - q)
                z = np.abs(jump[alarm]) / jump_sd
                label = "white" if not phi else f"AR(1) {phi}"
                print(f"{label:11s} {n:5d} {q:6.3f}  " + " ".join(f"{np.mean(z > t):5.2f}" for t in STEPS), flush=True)


if __name__ == "__main__":
    main()
