"""Step 4, spectrum: periodic structure and whiteness of the residuals (a periodogram over a long
stretch, lag correlations), for what no candidate explains."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import signal, stats
from statsmodels.stats.diagnostic import acorr_ljungbox

from .prepare import _Groups, _Samples, F64, I64


@dataclass
class _Long:
    """Per tightening fit of the long rundown stretch: level + quadratic drift + modulation."""

    gid: I64
    theta: F64
    resid: F64  # after the quadratic drift (for the periodogram)
    level: F64  # per tightening mean torque of the stretch
    span: F64  # per tightening angle span of the stretch
    count: F64


def _long_stretch(s: _Samples) -> _Long | None:
    if len(s.long_gid) == 0:
        return None
    n = s.n_tight
    cnt = np.bincount(s.long_gid, minlength=n).astype(np.float64)
    lo = np.full(n, np.inf)
    hi = np.full(n, -np.inf)
    np.minimum.at(lo, s.long_gid, s.long_theta)
    np.maximum.at(hi, s.long_gid, s.long_theta)
    span = np.where(cnt > 0, hi - lo, 0.0)
    level = np.bincount(s.long_gid, weights=s.long_y, minlength=n) / np.maximum(cnt, 1)
    resid = s.long_y - _poly_fit(s.long_gid, s.long_theta, s.long_y, n, [])[0]
    return _Long(s.long_gid, s.long_theta, resid, level, span, cnt)


def _poly_fit(gid: I64, theta: F64, y: F64, n: int, extra: list[F64]) -> tuple[F64, F64, F64]:
    """Per tightening least squares of y on (1, u, u^2, *extra), u the scaled angle.

    Returns (fitted, coefficients (n, 3 + len(extra)), coefficient variances (n, ...))."""
    present = np.unique(gid)
    remap = -np.ones(n, dtype=np.int64)
    remap[present] = np.arange(len(present))
    g = _Groups(remap[gid], len(present))
    um = g.mean(theta)[g.gid]
    us = np.sqrt(np.maximum(g.mean((theta - um) ** 2), 1e-12))[g.gid]
    u = (theta - um) / us
    cols = [np.ones_like(theta), u, u * u] + list(extra)
    coef, fitted = g.fit(cols, [y])
    res = y - fitted[:, 0]
    p = len(cols)
    sig2 = g.sum(res * res) / np.maximum(g.count - p, 1.0)
    XtX = np.empty((g.n, p, p))
    for a in range(p):
        for b in range(a, p):
            XtX[:, a, b] = XtX[:, b, a] = g.sum(cols[a] * cols[b])
    XtX[:, np.arange(p), np.arange(p)] += 1e-9 * (np.trace(XtX, axis1=1, axis2=2) / p)[:, None] + 1e-300
    var = np.diagonal(np.linalg.inv(XtX), axis1=1, axis2=2) * sig2[:, None]
    full_coef = np.full((n, p), np.nan)
    full_var = np.full((n, p), np.nan)
    full_coef[present] = coef[:, :, 0]
    full_var[present] = var
    return fitted[:, 0], full_coef, full_var


def _quadratic_detrend(v: F64) -> F64:
    """Each row (last axis) minus its least-squares quadratic: the drift a stretch keeps after the
    per-tightening fit over the whole long stretch."""
    x = np.arange(v.shape[-1], dtype=np.float64)
    rows = v.reshape(-1, v.shape[-1])
    trend = np.polynomial.polynomial.polyval(x, np.polynomial.polynomial.polyfit(x, rows.T, 2))
    out: F64 = (rows - trend).reshape(v.shape)
    return out


def _power_spectra(v: F64, grid_step: float) -> tuple[F64, F64]:
    """One-sided power spectra of the rows of ``v`` (uniform angle grid, ``grid_step`` deg):
    frequencies in cycles per degree and power in the unit of ``v`` squared.

    A Hann taper keeps the leakage of the strong low-frequency drift out of the higher bins;
    ``scaling="spectrum"`` puts a sine of amplitude A at A^2 / 2 in its bin."""
    freq, power = signal.periodogram(v, fs=1.0 / grid_step, window="hann", detrend=_quadratic_detrend, scaling="spectrum", axis=-1)
    return np.asarray(freq, dtype=np.float64), np.asarray(power, dtype=np.float64)


def _periodogram(lg: _Long | None, n_tight: int) -> dict[str, Any]:
    """Average periodogram of the long-stretch residual against angle (each stretch resampled
    onto a uniform angle grid, tapered, its power normalised to mean 1, then averaged)."""
    info: dict[str, Any] = {"window_deg": None, "peaks": [], "stretch": "rundown before the declared stretch, after a quadratic drift per tightening"}
    if lg is None:
        info["note"] = "no rundown before the declared stretch: periodicities over the angle cannot be examined"
        return info
    window = None
    for w in (720.0, 360.0, 180.0):
        if np.sum(lg.span >= w) >= max(20, 0.2 * n_tight):
            window = w
            break
    if window is None:
        info["note"] = "the rundown stretches are too short for a periodogram"
        return info
    n_grid = 512
    grid_step = window / n_grid
    order = np.argsort(lg.gid, kind="stable")
    gs, th, rr_all = lg.gid[order], lg.theta[order], lg.resid[order]
    starts = np.flatnonzero(np.r_[True, gs[1:] != gs[:-1]])
    ends = np.r_[starts[1:], len(gs)]
    stretches = []
    for b, e in zip(starts, ends):
        if lg.span[gs[b]] < window or e - b < 64:
            continue
        t, r = th[b:e], rr_all[b:e]
        o = np.argsort(t, kind="stable")
        t, r = t[o], r[o]
        grid = t[-1] - window + grid_step * np.arange(n_grid)
        stretches.append(np.interp(grid, t, r))
        if len(stretches) >= 3000:
            break
    freq, powers = np.zeros(0), np.zeros((0, 0))
    if stretches:
        freq, spectra = _power_spectra(np.array(stretches), grid_step)
        # each stretch normalised to mean power 1 (DC left out): noisy and quiet stretches weigh
        # alike in the average, and a peak reads as a ratio to the local background
        tot = spectra[:, 1:].mean(axis=1)
        powers = spectra[tot > 0] / tot[tot > 0, None]
    if len(powers) < 20:
        info["note"] = "too few long rundown stretches for a periodogram"
        return info
    P = np.mean(powers, axis=0)
    periods = np.r_[window, 1.0 / freq[1:]]
    # periods shorter than a few sample spacings are interpolation and aliasing, not data
    d_theta = np.diff(lg.theta)
    d_theta = d_theta[(np.diff(lg.gid) == 0) & (d_theta > 0)]
    spacing = float(np.median(d_theta)) if len(d_theta) else 0.0
    min_period = max(4.0 * spacing, 4.0 * grid_step)
    info["sample_spacing_deg"] = spacing
    info["shortest_period_deg"] = min_period
    info["window_deg"] = window
    info["segments"] = len(powers)
    keep_curve = periods[1:] >= min_period
    info["_curve"] = (periods[1:][keep_curve], P[1:][keep_curve])
    peaks = []
    se = 1.0 / math.sqrt(len(powers))
    # from the third bin on: the first two carry the drift left by the detrending and taper
    for i in range(3, len(P) - 1):
        lo, hi = max(1, i - 8), min(len(P), i + 9)
        neigh = float(np.median(np.r_[P[lo:i - 1], P[i + 2:hi]]))
        if periods[i] < min_period:
            break
        if P[i] >= P[i - 1] and P[i] >= P[i + 1] and P[i] > neigh * (1 + 10 * se) and P[i] > 1.5 * neigh:
            peaks.append({"period_deg": float(periods[i]), "power_ratio": float(P[i] / neigh)})
    peaks.sort(key=lambda p: -p["power_ratio"])
    info["peaks"] = peaks[:5]
    return info


# ---------------------------------------------------------------------------------------------
# Whiteness


def _ljung_box(r: F64, segment: I64, lags: int) -> dict[str, float]:
    """Ljung-Box Q at ``lags`` of each contiguous segment of ``r`` (a tightening's elastic window
    or rundown stretch: a series of its own, no lag reaches across), summed over the segments.

    Under whiteness each segment's Q is asymptotically chi-square with ``lags`` degrees of freedom
    and the segments are independent, so the sum is chi-square with the summed degrees of
    freedom. Segments of ``lags`` samples or fewer have no lag-``lags`` pair and are left out."""
    starts = np.flatnonzero(np.r_[True, segment[1:] != segment[:-1]])
    ends = np.r_[starts[1:], len(segment)]
    q_sum = 0.0
    used = rejected = 0
    for b, e in zip(starts, ends):
        if e - b <= lags:
            continue
        lb = acorr_ljungbox(r[b:e], lags=[lags], return_df=True)
        q_sum += float(lb["lb_stat"].iloc[0])
        rejected += int(float(lb["lb_pvalue"].iloc[0]) < 0.01)
        used += 1
    df = lags * used
    return {
        "q_sum": q_sum,
        "df": df,
        "p_value": float(stats.chi2.sf(q_sum, df)) if df else 1.0,
        # the chi-square standardised by its mean and sd: with tens of thousands of degrees of
        # freedom the p-value underflows, this still compares data sets
        "z": (q_sum - df) / math.sqrt(2 * df) if df else 0.0,
        "fraction_rejected_1pct": rejected / used if used else float("nan"),
    }


def _whiteness(s: _Samples, r: F64, lags: int = 10) -> dict[str, Any]:
    key = s.gid * 2 + s.seg
    n = len(r)
    acf = []
    X = np.zeros((n, lags))
    valid = np.ones(n, dtype=bool)
    for k in range(1, lags + 1):
        i = np.arange(k, n)
        same = key[i] == key[i - k]
        prod = np.where(same, r[i] * r[i - k], 0.0)
        acf.append(float(prod.sum() / max(np.sum(r * r), 1e-300)))
        X[k:, k - 1] = np.where(same, r[:-k], 0.0)
        valid[k:] &= same
        valid[:k] = False
    lb = _ljung_box(r, key, lags)
    # pooled AR(lags) predictability of the residual from its own past (effect size)
    Xv, rv = X[valid], r[valid]
    r2 = 0.0
    if len(rv) > 10 * lags:
        coef, *_ = np.linalg.lstsq(Xv, rv, rcond=None)
        pred = Xv @ coef
        r2 = float(1 - np.sum((rv - pred) ** 2) / max(np.sum(rv * rv), 1e-300))
    # Wald-Wolfowitz runs test on signs within segments, pooled: the total count of runs is a sum
    # over thousands of independent segments, each with its exact null mean and variance, so a
    # normal reference is right for it (central limit theorem over segments); reported as a z.
    sg = r > 0
    new = np.r_[True, key[1:] != key[:-1]]
    runs = np.sum(new | (sg != np.r_[~sg[0], sg[:-1]]))
    n1 = np.bincount(key, weights=sg.astype(float))
    nn = np.bincount(key).astype(float)
    n2 = nn - n1
    okk = nn > 1
    mu = np.sum(np.where(okk, 2 * n1 * n2 / np.maximum(nn, 1) + 1, 1))
    var = np.sum(np.where(okk, 2 * n1 * n2 * (2 * n1 * n2 - nn) / np.maximum(nn**2 * (nn - 1), 1), 0))
    z_runs = float((runs - mu) / math.sqrt(var)) if var > 0 else 0.0
    return {
        "lag_autocorrelation": acf,
        "ljung_box_q_sum": lb["q_sum"],
        "ljung_box_df": lb["df"],
        "ljung_box_z": lb["z"],
        "ljung_box_p_value": lb["p_value"],
        "ljung_box_fraction_rejected_1pct": lb["fraction_rejected_1pct"],
        "ar_r2": r2,
        "runs_test_z": z_runs,
        "note": "ljung_box: Q at lag 10 per segment (elastic window, rundown stretch), summed; "
        "ar_r2: fraction of the residual variance predictable from its own past 10 samples (pooled AR(10)); "
        "with thousands of tightenings any autocorrelation is 'significant', so the structure flag uses this effect size",
    }
