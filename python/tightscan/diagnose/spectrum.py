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
    t: F64 | None = None  # time within the tightening [s] (None without a time channel)
    ref: F64 | None = None  # per tightening reference torque: the target, else the peak torque [Nm]
    y: F64 | None = None  # the measured torque of the stretch


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
    ref = np.where(np.isfinite(s.target) & (s.target > 0), s.target, s.scale)
    return _Long(s.long_gid, s.long_theta, resid, level, span, cnt, s.long_t, ref, s.long_y)


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


# Welch segments with half overlap and a Hann taper: the correlation of the ordinates of two
# overlapping segments is rho = 0.167, so K segments carry the information of K / (1 + 2 rho^2)
_HANN_HALF_OVERLAP = 1.0 / (1.0 + 2.0 * 0.167**2)
_ANGLE_WINDOWS = (1440.0, 1080.0, 720.0)  # several periods of the longest period sought (360 deg)
_FIRST_BIN = 3  # the first bins carry the drift left by the detrending and the taper
_NEIGHBOURS = 10  # background from the bins 2..10 either side (the Hann main lobe is +-2 bins)


@dataclass
class _Domain:
    """Welch spectra of the long-stretch residual against one axis (angle or time)."""

    name: str  # "angle" | "time"
    unit: str  # "deg" | "s"
    window: float
    step: float
    n_grid: int
    spacing: float  # median sample spacing on this axis
    owners: I64  # tightening of each segment


def _axis(lg: _Long, domain: str) -> F64 | None:
    return lg.theta if domain == "angle" else lg.t


def _spans(gid: I64, u: F64, n: int) -> F64:
    lo = np.full(n, np.inf)
    hi = np.full(n, -np.inf)
    np.minimum.at(lo, gid, u)
    np.maximum.at(hi, gid, u)
    return np.where(hi > lo, hi - lo, 0.0)


def _choose_domain(lg: _Long, domain: str, n_tight: int) -> _Domain | None:
    """Window of the Welch segments: on the angle, the longest of 4, 3, 2 revolutions that enough
    tightenings hold (at least 20 and a fifth of them), so that the longest period searched
    (one revolution) has several periods in a window; on time, the time those revolutions take
    at the stretch's median speed (or the longest of 1, 3/4, 1/2 of it that enough hold)."""
    u = _axis(lg, domain)
    if u is None or len(u) == 0:
        return None
    spans = _spans(lg.gid, u, n_tight)
    need = max(20, 0.2 * n_tight)
    du = np.diff(u)
    du = du[(np.diff(lg.gid) == 0) & (du > 0)]
    if len(du) == 0:
        return None
    spacing = float(np.median(du))
    if domain == "angle":
        ladder = list(_ANGLE_WINDOWS)
    else:
        dth = np.diff(lg.theta)
        ok = (np.diff(lg.gid) == 0) & (np.diff(u) > 0)
        speed = float(np.median(dth[ok] / np.diff(u)[ok])) if ok.any() else 0.0
        if not speed > 0:
            return None
        longest = max(_ANGLE_WINDOWS) / speed
        ladder = [longest, 0.75 * longest, 0.5 * longest, 0.25 * longest]
    window = next((w for w in ladder if np.sum(spans >= w * 0.999) >= need), None)
    if window is None:
        return None
    # at least one grid point per sample (no aliasing by the resampling), at most 4096 points
    n_grid = int(min(4096, max(256, 2 ** math.ceil(math.log2(window / spacing)))))
    return _Domain(domain, "deg" if domain == "angle" else "s", window, window / n_grid, n_grid, spacing, np.zeros(0, dtype=np.int64))


def _segments(lg: _Long, dom: _Domain, r: F64, cap: int = 2000) -> tuple[F64, I64]:
    """Each tightening's stretch resampled on a uniform grid of ``dom.step`` and cut into
    windows of ``dom.n_grid`` points with half overlap, aligned to the end of the stretch."""
    u = _axis(lg, dom.name)
    assert u is not None
    order = np.lexsort((u, lg.gid))
    gs, uu, rr = lg.gid[order], u[order], r[order]
    starts = np.flatnonzero(np.r_[True, gs[1:] != gs[:-1]])
    ends = np.r_[starts[1:], len(gs)]
    hop = dom.n_grid // 2
    rows: list[F64] = []
    owners: list[int] = []
    total = 0
    # the tightenings in a fixed pseudo-random order, so that a cap keeps a spread of them
    for k in np.random.default_rng(0).permutation(len(starts)):
        b, e = starts[k], ends[k]
        if e - b < 16 or uu[e - 1] - uu[b] < dom.window * 0.999:
            continue
        n_pts = int(math.floor((uu[e - 1] - uu[b]) / dom.step)) + 1
        if n_pts < dom.n_grid:
            continue
        grid = uu[e - 1] - dom.step * np.arange(n_pts)[::-1]
        v = np.interp(grid, uu[b:e], rr[b:e])
        n_seg = 1 + max(0, (n_pts - dom.n_grid) // hop)
        for q in range(n_seg):
            stop = n_pts - q * hop
            rows.append(v[stop - dom.n_grid : stop])
            owners.append(int(gs[b]))
        total += n_seg
        if total >= cap:
            break
    if not rows:
        return np.zeros((0, dom.n_grid)), np.zeros(0, dtype=np.int64)
    return np.array(rows), np.array(owners, dtype=np.int64)


def _peak_table(freq: F64, P: F64, Q: F64, raw: F64, n_seg: int, overlap: bool, lo_bin: int, hi_bin: int) -> dict[str, F64]:
    """Per bin of the averaged normalised spectrum ``P`` (mean of the squares ``Q``): its ratio to
    the background (median of the neighbouring bins), the chi-square p-value of that ratio and the
    lobe's excess power (share of the total, and in the unit of ``raw`` squared).

    Under no periodicity an ordinate of one segment is its background times chi2_2 / 2, so the
    mean of ``n_seg`` of them is the background times chi2_nu / nu, nu = 2 n_seg. Segments of
    unequal spectral shape (noisy and quiet tightenings) make the mean more variable than that:
    nu is reduced by the ratio of E[p^2] / E[p]^2 (2 for chi2_2) measured on the neighbours, and
    for the half overlap of the segments."""
    nb = len(P)
    bg = np.full(nb, np.nan)
    c = np.full(nb, np.nan)
    bg_raw = np.full(nb, np.nan)
    shape = Q / np.maximum(P * P, 1e-300)
    for i in range(max(1, lo_bin - 2), min(nb, hi_bin + 3)):
        idx = np.r_[np.arange(max(1, i - _NEIGHBOURS), max(1, i - 1)), np.arange(min(nb, i + 2), min(nb, i + _NEIGHBOURS + 1))]
        if len(idx) < 4:
            continue
        bg[i] = np.median(P[idx])
        c[i] = np.median(shape[idx])
        bg_raw[i] = np.median(raw[idx])
    nu = 2.0 * n_seg * 2.0 / np.maximum(c, 2.0) * (_HANN_HALF_OVERLAP if overlap else 1.0)
    ratio = P / np.where(bg > 0, bg, np.nan)
    p = np.where(np.isfinite(ratio), stats.chi2.sf(nu * np.nan_to_num(ratio), np.nan_to_num(nu, nan=2.0)), 1.0)
    excess = np.zeros(nb)
    excess_raw = np.zeros(nb)
    for i in range(lo_bin, hi_bin):
        if not np.isfinite(bg[i]):
            continue
        lobe = slice(max(1, i - 2), min(nb, i + 3))
        excess[i] = float(np.sum(P[lobe]) - bg[i] * (lobe.stop - lobe.start))
        excess_raw[i] = float(np.sum(raw[lobe]) - bg_raw[i] * (lobe.stop - lobe.start))
    total = float(np.sum(P[1:]))
    return {"bg": bg, "ratio": ratio, "p": p, "share": excess / max(total, 1e-300), "excess_raw": excess_raw, "nu": nu}


def _domain_spectrum(lg: _Long, dom: _Domain, r: F64) -> dict[str, Any] | None:
    rows, owners = _segments(lg, dom, r)
    if len(rows) < 20:
        return None
    freq, spectra = _power_spectra(rows, dom.step)
    tot = spectra[:, 1:].mean(axis=1)
    ok = tot > 0
    norm = spectra[ok] / tot[ok, None]
    min_period = max(4.0 * dom.spacing, 4.0 * dom.step)
    hi_bin = int(min(len(freq) - 2, math.floor(dom.window / min_period)))
    overlap = len(np.unique(owners)) < len(owners)
    return {
        "freq": freq,
        "P": norm.mean(axis=0),
        "Q": (norm * norm).mean(axis=0),
        "raw": spectra[ok].mean(axis=0),
        "segments": int(ok.sum()),
        "tightenings": int(len(np.unique(owners[ok]))),
        "overlap": overlap,
        "lo_bin": _FIRST_BIN,
        "hi_bin": max(hi_bin, _FIRST_BIN),
        "min_period": min_period,
    }


def _find_peaks(sp: dict[str, Any], dom: _Domain, lg: _Long, tests: int, alpha: float, share_min: float) -> tuple[list[dict[str, Any]], dict[str, F64]]:
    tab = _peak_table(sp["freq"], sp["P"], sp["Q"], sp["raw"], sp["segments"], sp["overlap"], sp["lo_bin"], sp["hi_bin"])
    P, freq = sp["P"], sp["freq"]
    ref = float(np.nanmedian(lg.ref)) if lg.ref is not None and np.any(np.isfinite(lg.ref)) else float("nan")
    peaks: list[dict[str, Any]] = []
    for i in range(sp["lo_bin"], sp["hi_bin"]):
        if not (P[i] >= P[i - 1] and P[i] >= P[i + 1]):
            continue
        p_adj = min(1.0, float(tab["p"][i]) * tests)
        if not (p_adj < alpha and tab["share"][i] >= share_min):
            continue
        lobe = np.arange(max(1, i - 1), min(len(P), i + 2))
        w = np.maximum(P[lobe] - tab["bg"][i], 0.0)
        f_c = float(np.sum(freq[lobe] * w) / np.sum(w)) if np.sum(w) > 0 else float(freq[i])
        # a sine of amplitude A puts A^2 / 2 times the Hann window's noise bandwidth (1.5 bins)
        # into its lobe of the 'spectrum'-scaled periodogram
        amp = math.sqrt(max(2.0 * float(tab["excess_raw"][i]) / 1.5, 0.0))
        peaks.append(
            {
                "domain": dom.name,
                f"period_{dom.unit}": 1.0 / f_c,
                "frequency": f_c,
                "frequency_unit": "cycles per degree" if dom.name == "angle" else "Hz",
                "power_ratio": float(tab["ratio"][i]),
                "p_value": p_adj,
                "power_share": float(tab["share"][i]),
                "amplitude_nm": amp,
                "amplitude_fraction_of_reference": amp / ref if ref > 0 else float("nan"),
            }
        )
    peaks.sort(key=lambda q: -q["power_ratio"])
    # a peak within the lobes of a stronger one (4 bins) is its leakage, not a periodicity
    kept: list[dict[str, Any]] = []
    for q in peaks:
        if all(abs(q["frequency"] - k["frequency"]) * dom.window > 4.0 for k in kept):
            kept.append(q)
    return kept, tab


def _refine_period(lg: _Long, axis: str, period: float, window: float, n_tight: int) -> float:
    """The period of a spectral peak refined to well within a bin: the frequency (within a bin
    either side) whose sine and cosine per tightening, fitted to the drift-free residual of the
    long stretch, take up the most of it (a parabola through the best of nine trial
    frequencies). Per tightening the 2 x 2 normal equations, from sums over its samples."""
    u = _axis(lg, axis)
    if u is None:
        return period
    spans = lg.span if axis == "angle" else _spans(lg.gid, u, n_tight)
    held = np.flatnonzero(spans >= period)
    # a spread of at most 500 tightenings locates the period well within a bin
    held = held[:: max(1, len(held) // 500)]
    sel = np.zeros(n_tight, dtype=bool)
    sel[held] = True
    sel = sel[lg.gid]
    if sel.sum() < 100:
        return period
    gid, r, uu = lg.gid[sel], lg.resid[sel], u[sel]
    f0, df = 1.0 / period, 1.0 / window

    def taken_up(f: float) -> float:
        ph = 2 * math.pi * f * uu
        sn, cs = np.sin(ph), np.cos(ph)

        def tot(v: F64) -> F64:
            out: F64 = np.asarray(np.bincount(gid, weights=v, minlength=n_tight), dtype=np.float64)
            return out

        a, b, c = tot(sn * sn), tot(sn * cs), tot(cs * cs)
        p, q = tot(sn * r), tot(cs * r)
        det = a * c - b * b
        ok = det > 1e-12 * np.maximum(a * c, 1e-300)
        red = np.where(ok, (c * p * p - 2 * b * p * q + a * q * q) / np.where(ok, det, 1.0), 0.0)
        return float(np.sum(red))

    fs = f0 + df * np.linspace(-1.0, 1.0, 9)
    fs = fs[fs > 0]
    vals = np.array([taken_up(float(f)) for f in fs])
    k = int(np.argmax(vals))
    # no maximum inside the bin either side (a broad or weak peak): the peak's own centroid
    f_best = float(fs[k]) if 0 < k < len(fs) - 1 else f0
    if 0 < k < len(fs) - 1:
        lo, mid, hi = vals[k - 1], vals[k], vals[k + 1]
        den = lo - 2 * mid + hi
        if den < 0:
            cand = float(fs[k] + 0.5 * (lo - hi) / den * (fs[1] - fs[0]))
            if taken_up(cand) > mid:
                f_best = cand
    return 1.0 / f_best


def _lsd(a: F64, b: F64) -> float:
    """Log-spectral distance in dB: the root mean square of 10 log10(a / b) over the bins."""
    ok = (a > 0) & (b > 0)
    return float(np.sqrt(np.mean((10.0 * np.log10(a[ok] / b[ok])) ** 2))) if ok.any() else float("nan")


def _spectral_search(lg: _Long | None, n_tight: int, alpha: float = 0.01, min_gain: float = 0.01, remove: list[tuple[str, float]] | None = None, before: dict[str, Any] | None = None) -> dict[str, Any]:
    """Spectral search over the long-stretch residual against the angle and against time.

    Per axis: each tightening's stretch (after its quadratic drift) resampled on a uniform grid,
    cut in Welch segments of a few revolutions with half overlap, Hann-tapered, each segment's
    power normalised to mean 1 and averaged across all tightenings (the phase may differ in
    every tightening: the power does not). A bin is a peak when it is a local maximum whose
    ratio to the background of its neighbours is significant (chi-square, Bonferroni over every
    bin searched on both axes, ``alpha``) and whose lobe holds at least 1 - (1 - min_gain)^2 of
    the residual power (what removing it would gain in RMSE: ``min_gain``).

    ``remove``: the periodic terms of the model, (axis, period): a sine and cosine each per
    tightening fitted with the drift, and the spectra recomputed; ``before`` (this function's
    output without ``remove``) then gives the log-spectral distance between the two."""
    out: dict[str, Any] = {
        "stretch": "rundown before the declared stretch, after a quadratic drift per tightening",
        "alpha": alpha,
        "min_power_share": 1.0 - (1.0 - min_gain) ** 2,
        "peaks": [],
        "axes": {},
    }
    if lg is None:
        out["note"] = "no rundown before the declared stretch: periodicities cannot be examined"
        return out
    r = lg.resid
    if remove:
        extra = []
        for axis, period in remove:
            u = _axis(lg, axis)
            if u is None:
                continue
            ph = 2 * math.pi * u / period
            extra += [np.sin(ph), np.cos(ph)]
        if extra and lg.y is not None:
            r = lg.y - _poly_fit(lg.gid, lg.theta, lg.y, n_tight, extra)[0]
        out["removed"] = [{"axis": a, "period": p} for a, p in remove]
    doms = [d for d in (_choose_domain(lg, "angle", n_tight), _choose_domain(lg, "time", n_tight)) if d is not None]
    spectra = {}
    for dom in doms:
        sp = _domain_spectrum(lg, dom, r)
        if sp is not None:
            spectra[dom.name] = (dom, sp)
    if not spectra:
        out["note"] = "the rundown stretches are too short or too few for a spectrum"
        return out
    tests = sum(max(sp["hi_bin"] - sp["lo_bin"], 1) for _, sp in spectra.values())
    out["bins_searched"] = tests
    for name, (dom, sp) in spectra.items():
        peaks, tab = _find_peaks(sp, dom, lg, tests, alpha, out["min_power_share"])
        keep = np.arange(sp["lo_bin"], sp["hi_bin"])
        ax: dict[str, Any] = {
            f"window_{dom.unit}": dom.window,
            f"grid_step_{dom.unit}": dom.step,
            f"sample_spacing_{dom.unit}": dom.spacing,
            f"shortest_period_{dom.unit}": sp["min_period"],
            f"longest_period_{dom.unit}": dom.window / sp["lo_bin"],
            "segments": sp["segments"],
            "tightenings": sp["tightenings"],
            # the seed's log-spectral distance of the averaged spectrum from its smoothed
            # background (0 dB: featureless) over the bins searched
            "distance_from_background_db": _lsd(sp["P"][keep], tab["bg"][keep]),
        }
        if before is not None and name in before.get("_spectra", {}):
            P0 = before["_spectra"][name]
            if len(P0) == len(sp["P"]):
                ax["log_spectral_distance_db"] = _lsd(sp["raw"][keep], P0[keep])
        out["axes"][name] = ax
        out["peaks"] += peaks
        out.setdefault("_spectra", {})[name] = sp["raw"]
        if name == "angle":
            per = 1.0 / sp["freq"][keep]
            out["_curve"] = (per, sp["P"][keep])
    out["peaks"].sort(key=lambda q: -q["power_ratio"])
    return out


def _periodogram(lg: _Long | None, n_tight: int, alpha: float = 0.01, min_gain: float = 0.01, search: dict[str, Any] | None = None) -> dict[str, Any]:
    """The angle part of :func:`_spectral_search` in the layout of ``details["periodogram"]``."""
    info: dict[str, Any] = {"window_deg": None, "peaks": [], "stretch": "rundown before the declared stretch, after a quadratic drift per tightening"}
    sr = search if search is not None else _spectral_search(lg, n_tight, alpha, min_gain)
    ax = sr.get("axes", {}).get("angle")
    if ax is None:
        info["note"] = sr.get("note", "the rundown stretches are too short for a periodogram")
        return info
    info["sample_spacing_deg"] = ax["sample_spacing_deg"]
    info["shortest_period_deg"] = ax["shortest_period_deg"]
    info["window_deg"] = ax["window_deg"]
    info["segments"] = ax["segments"]
    if "_curve" in sr:
        info["_curve"] = sr["_curve"]
    info["peaks"] = [
        {"period_deg": q["period_deg"], "power_ratio": q["power_ratio"], "p_value": q["p_value"], "amplitude_nm": q["amplitude_nm"]}
        for q in sr["peaks"]
        if q["domain"] == "angle"
    ][:5]
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
