"""The peers of the detection-quality benchmark: off-the-shelf change-point methods (ruptures
Binseg and Pelt with a linear cost, statsmodels OLS-CUSUM, river PageHinkley and ADWIN), each
handed the TRUE elastic window of a curve, and their calibration to a matched false-alarm rate.
Used by ``detection_quality.py``."""

from __future__ import annotations

import math
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from typing import Any, Callable, Iterable, TypeVar

import numpy as np
import pyarrow as pa

from scoring import rate
FA_TARGET = 0.01  # matched false-alarm rate per curve

# Peers' window: samples recorded below this speed are left out. The slowest programmed speed
# of the simulated tools is 10 rpm (CSDT second step) and the speed channel's noise is 0.5 rpm,
# so this drops the CSDT pause (angle held while the torque relaxes: no torque-angle slope) and
# the last samples of the HDT coast-down, nothing else.
STOP_RPM = 5.0

T = TypeVar("T")


@dataclass
class PeerCurve:
    """What a peer is handed: one tightening's true elastic zone, angle and torque only."""

    row: int  # row in the set's frame
    angle: np.ndarray
    torque: np.ndarray


def peer_windows(curves: pa.Table, window_start: np.ndarray, window_end: np.ndarray, rows: Iterable[int], first_row: int) -> list[PeerCurve]:
    """The true elastic zone of each selected tightening: angle in [window_start, window_end]
    (from the generator's truth table: the built-in simulator's ``elastic_start_angle`` and
    ``final_angle``, the independent generator's ``window_start_angle`` and
    ``window_end_angle``), recorded speed >= STOP_RPM."""
    angle = curves.column("angle").combine_chunks()
    offsets = angle.offsets.to_numpy()
    a_all = angle.values.to_numpy(zero_copy_only=False)
    t_all = curves.column("torque").combine_chunks().values.to_numpy(zero_copy_only=False)
    s_all = curves.column("speed").combine_chunks().values.to_numpy(zero_copy_only=False)
    lo, hi = np.asarray(window_start, dtype=np.float64), np.asarray(window_end, dtype=np.float64)
    out = []
    for i in rows:
        s, e = offsets[i], offsets[i + 1]
        a = a_all[s:e].astype(np.float64)
        keep = (a >= lo[i]) & (a <= hi[i]) & (s_all[s:e] >= STOP_RPM)
        out.append(PeerCurve(first_row + i, a[keep], t_all[s:e][keep].astype(np.float64)))
    return out


# ---------------------------------------------------------------------------------------------
# Peers (run in worker processes)


def _make_linear_cost() -> Any:
    """ruptures' ``CostLinear`` (least-squares line fit per segment) from prefix sums: the same
    cost in O(1) per segment instead of an lstsq per call, so that Binseg can scan every split
    (jump 1) and Pelt is affordable. Equality with ``CostLinear`` is checked in the run.

    Signal layout as for CostLinear: column 0 the observation (torque), then the regressors
    (angle, 1). A segment whose angle does not vary costs its sum of squares about the mean
    (CostLinear's lstsq returns an empty residual, i.e. 0, for such a rank-deficient segment)."""
    from ruptures.base import BaseCost
    from ruptures.exceptions import NotEnoughPoints

    class _Cost(BaseCost):  # type: ignore[misc]
        model = "linear_prefix_sums"

        def __init__(self, min_size: int = 2) -> None:
            self.min_size = min_size
            self.signal: np.ndarray | None = None

        def fit(self, signal: np.ndarray) -> "_Cost":
            self.signal = signal
            y = signal[:, 0] - signal[:, 0].mean()
            x = signal[:, 1] - signal[:, 1].mean()
            z = np.zeros(1)
            self.c = [np.concatenate((z, np.cumsum(v))) for v in (x, y, x * x, x * y, y * y)]
            return self

        def error(self, start: int, end: int) -> float:
            n = end - start
            if n < self.min_size:
                raise NotEnoughPoints
            sx, sy, sxx, sxy, syy = (c[end] - c[start] for c in self.c)
            sxx_c = sxx - sx * sx / n
            sxy_c = sxy - sx * sy / n
            syy_c = syy - sy * sy / n
            r = syy_c - sxy_c * sxy_c / sxx_c if sxx_c > 1e-12 * max(sxx, 1e-300) else syy_c
            return float(max(r, 0.0))

    return _Cost


@dataclass
class Prepared:
    """A peer curve in the form the peers read."""

    angle: np.ndarray  # deg, as recorded
    y: np.ndarray  # torque / noise scale (unit noise)
    w: int  # samples per rate window
    z: np.ndarray  # local torque rate per window / robust scale of the rate series
    rate_first: np.ndarray  # index of each rate window's first sample
    rate_last: np.ndarray  # index of its last sample (when a streaming peer has seen it)


@dataclass(frozen=True)
class PeerSettings:
    """Per-curve preprocessing and peer parameters, read from our default config where they
    have a counterpart so that peers and ours work at the same resolution."""

    min_samples: int  # zone_min_samples: fewer samples in the window: the peer cannot run
    max_windows: int  # max_blocks: at most this many rate windows
    min_window: int  # min_block_samples: at least this many samples per rate window
    burn_in: int  # min_training_blocks: PageHinkley min_instances, ADWIN grace_period
    ph_delta: float  # kappa: PageHinkley's allowance, in units of the rate series' noise
    pelt_jump: int


def prepare(angle: np.ndarray, torque: np.ndarray, s: PeerSettings) -> Prepared | None:
    """Noise-normalised torque and the local torque-rate series of one window.

    Rate windows: consecutive runs of ``w = max(min_window, ceil(n / max_windows))`` samples (the
    remainder joins the last), each window's least-squares slope of torque over angle. The torque
    noise scale (which includes the angle quantisation seen through the slope) is the median of
    the windows' residual variances, corrected to a mean by the chi-square median; a change
    affects few windows, so it barely moves the median. The rate series is divided by a robust
    scale of its first differences (MAD / sqrt 2), which a single step does not inflate."""
    from scipy import stats

    n = angle.size
    if n < s.min_samples:
        return None
    w = max(s.min_window, math.ceil(n / s.max_windows))
    nb = n // w
    if nb < 3:
        return None
    starts = np.arange(nb) * w
    x = angle - angle.mean()
    y = torque - torque.mean()
    cnt = np.diff(np.append(starts, n)).astype(np.float64)
    sx, sy = np.add.reduceat(x, starts), np.add.reduceat(y, starts)
    sxx, sxy, syy = np.add.reduceat(x * x, starts), np.add.reduceat(x * y, starts), np.add.reduceat(y * y, starts)
    sxx_c = sxx - sx * sx / cnt
    sxy_c = sxy - sx * sy / cnt
    syy_c = syy - sy * sy / cnt
    valid = sxx_c > 1e-9 * np.maximum(sxx, 1e-300)
    if valid.sum() < 3:
        return None
    slope = sxy_c[valid] / sxx_c[valid]
    df = cnt[valid] - 2.0
    var_b = np.maximum(syy_c[valid] - sxy_c[valid] ** 2 / sxx_c[valid], 0.0) / df
    dfm = float(np.median(df))
    sigma2 = float(np.median(var_b)) / (stats.chi2.ppf(0.5, dfm) / dfm)
    if not sigma2 > 0:
        return None
    d = np.diff(slope)
    scale = 1.4826 * float(np.median(np.abs(d - np.median(d)))) / math.sqrt(2.0)
    if not scale > 0:
        scale = float(np.std(slope)) or 1.0
    last = np.append(starts[1:], n) - 1
    return Prepared(angle, y / math.sqrt(sigma2), w, slope / scale, starts[valid], last[valid])


def _binseg_one(algo_signal: np.ndarray, cost: Any, min_size: int) -> tuple[float, int]:
    """ruptures Binseg, one break: its location and the cost reduction it brings."""
    import ruptures as rpt

    n = algo_signal.shape[0]
    algo = rpt.Binseg(custom_cost=cost, min_size=min_size, jump=1).fit(algo_signal)
    bkp = algo.predict(n_bkps=1)[0]
    gain = algo.cost.error(0, n) - algo.cost.error(0, bkp) - algo.cost.error(bkp, n)
    return float(gain), int(bkp)


def _ph_trace(z: np.ndarray, s: PeerSettings, threshold: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, int | None]:
    """river PageHinkley over the rate series. Returns, per step, the two one-sided statistics
    (read from the detector's state, 0 before ``min_instances``), the index where each side's
    cumulative sum last reached its extreme (Page's change-start estimate), and the index of
    river's first ``drift_detected`` at ``threshold`` (None if none)."""
    from river import drift

    ph = drift.PageHinkley(min_instances=s.burn_in, delta=s.ph_delta, threshold=threshold, mode="both")
    up, down = np.zeros(z.size), np.zeros(z.size)
    arg_up, arg_down = np.zeros(z.size, dtype=np.int64), np.zeros(z.size, dtype=np.int64)
    best_up, best_down = math.inf, -math.inf
    i_up = i_down = 0
    alarm = None
    for i, v in enumerate(z):
        ph.update(float(v))  # type: ignore[no-untyped-call]
        # river's private state: _sum_increase/_min_increase (upward test), _sum_decrease/
        # _max_decrease (downward test); the test statistics are their differences.
        if ph._sum_increase < best_up:
            best_up, i_up = ph._sum_increase, i
        if ph._sum_decrease > best_down:
            best_down, i_down = ph._sum_decrease, i
        arg_up[i], arg_down[i] = i_up, i_down
        if i + 1 >= s.burn_in:
            up[i] = ph._sum_increase - ph._min_increase
            down[i] = ph._max_decrease - ph._sum_decrease
        if ph.drift_detected and alarm is None:
            alarm = i
            break
    return up, down, np.stack([arg_up, arg_down]), alarm


def _adwin_run(z: np.ndarray, delta: float, s: PeerSettings) -> tuple[int | None, int]:
    """river ADWIN over the rate series, checking at every item (clock 1: a curve has at most
    ``max_windows`` rates). Returns the first detection index and the window width after it."""
    from river import drift

    ad = drift.ADWIN(delta=delta, clock=1, grace_period=s.burn_in)  # type: ignore[no-untyped-call]
    for i, v in enumerate(z):
        ad.update(float(v))  # type: ignore[no-untyped-call]
        if ad.drift_detected:
            return i, int(ad.width)
    return None, 0


# ADWIN's delta is a confidence in (0, 1); on a few dozen rates it rarely fires even near 1.
ADWIN_LOG10_RANGE = (-15.0, math.log10(0.99))


def _adwin_critical(z: np.ndarray, s: PeerSettings) -> float:
    """-log10 of the smallest delta at which ADWIN fires on this series (it fires for every
    larger delta), by bisection on log10(delta); -inf if it does not fire at delta 0.99."""
    lo, hi = ADWIN_LOG10_RANGE
    if _adwin_run(z, 10.0**hi, s)[0] is None:
        return -math.inf
    if _adwin_run(z, 10.0**lo, s)[0] is not None:
        return -lo
    for _ in range(24):
        mid = 0.5 * (lo + hi)
        if _adwin_run(z, 10.0**mid, s)[0] is None:
            lo = mid
        else:
            hi = mid
    return -hi


def peer_statistics(args: tuple[PeerCurve, PeerSettings]) -> dict[str, Any]:
    """Threshold-free part of every peer on one curve: continuous statistics and, for the
    one-break methods, the break location (as an angle). ``seconds`` holds each peer's CPU time
    (the shared preprocessing under ``prepare``)."""
    from statsmodels.stats.diagnostic import breaks_cusumolsresid

    import ruptures as rpt

    curve, s = args
    clock = time.process_time
    t0 = clock()
    p = prepare(curve.angle, curve.torque, s)
    secs: dict[str, float] = {"prepare": clock() - t0}
    out: dict[str, Any] = {"row": curve.row, "ran": p is not None, "n": int(curve.angle.size), "seconds": secs}
    if p is None:
        return out
    n = p.y.size
    t0 = clock()
    sig = np.column_stack((p.y, p.angle, np.ones(n)))
    gain, bkp = _binseg_one(sig, _make_linear_cost()(min_size=p.w), p.w)
    out["binseg_linear"] = (gain, float(p.angle[bkp]))
    t1 = clock()
    algo = rpt.Binseg(model="l2", min_size=2, jump=1).fit(p.z.reshape(-1, 1))
    b = algo.predict(n_bkps=1)[0]
    g = algo.cost.error(0, p.z.size) - algo.cost.error(0, b) - algo.cost.error(b, p.z.size)
    out["binseg_l2_rate"] = (float(g), float(p.angle[p.rate_first[b]]))
    t2 = clock()
    up, down, _, _ = _ph_trace(p.z, s, math.inf)
    out["pagehinkley"] = float(max(up.max(), down.max()))
    t3 = clock()
    out["adwin"] = _adwin_critical(p.z, s)
    t4 = clock()
    # OLS-CUSUM (Ploberger-Kramer) on the residuals of one line torque ~ angle over the window;
    # its location estimate is the first sample after the peak of the residual cumsum.
    design = np.column_stack((np.ones(n), p.angle - p.angle.mean()))
    beta, *_ = np.linalg.lstsq(design, p.y, rcond=None)
    resid = p.y - design @ beta
    _, pval, _ = breaks_cusumolsresid(resid, ddof=2)
    at = min(int(np.argmax(np.abs(np.cumsum(resid)))) + 1, n - 1)
    out["ols_cusum"] = (-math.log10(max(float(pval), 1e-300)), float(p.angle[at]))
    t5 = clock()
    secs.update({"binseg_linear": t1 - t0, "binseg_l2_rate": t2 - t1, "pagehinkley": t3 - t2,
                 "adwin": t4 - t3, "ols_cusum": t5 - t4})
    return out


def pelt_fires(args: tuple[PeerCurve, PeerSettings, str, float]) -> tuple[int, bool, float, float]:
    """ruptures Pelt at penalty ``pen`` on one curve: (row, any break, angle of the first break,
    CPU seconds)."""
    import ruptures as rpt

    curve, s, which, pen = args
    t0 = time.process_time()
    p = prepare(curve.angle, curve.torque, s)
    if p is None:
        return curve.row, False, math.nan, time.process_time() - t0
    if which == "pelt_linear":
        sig = np.column_stack((p.y, p.angle, np.ones(p.y.size)))
        algo = rpt.Pelt(custom_cost=_make_linear_cost()(min_size=p.w), min_size=p.w, jump=s.pelt_jump).fit(sig)
        bkps = algo.predict(pen=pen)
        at = float(p.angle[bkps[0]]) if len(bkps) > 1 else math.nan
    else:
        algo = rpt.Pelt(model="l2", min_size=2, jump=1).fit(p.z.reshape(-1, 1))
        bkps = algo.predict(pen=pen)
        at = float(p.angle[p.rate_first[bkps[0]]]) if len(bkps) > 1 else math.nan
    return curve.row, len(bkps) > 1, at, time.process_time() - t0


def peer_streaming(args: tuple[PeerCurve, PeerSettings, float, float]) -> dict[str, Any]:
    """PageHinkley and ADWIN at their calibrated settings: alarm angle (end of the rate window
    that triggered) and change-start estimate (PageHinkley: where the alarming side's sum last
    reached its extreme; ADWIN: the first rate of the window it keeps after the cut)."""
    curve, s, ph_threshold, adwin_delta = args
    clock = time.process_time
    t0 = clock()
    p = prepare(curve.angle, curve.torque, s)
    secs: dict[str, float] = {"prepare": clock() - t0}
    out: dict[str, Any] = {"row": curve.row, "seconds": secs}
    if p is None:
        return out
    t0 = clock()
    up, down, extremes, alarm = _ph_trace(p.z, s, ph_threshold)
    if alarm is not None:
        side = 0 if up[alarm] > ph_threshold else 1
        start = min(int(extremes[side, alarm]) + 1, p.z.size - 1)
        out["pagehinkley"] = (float(p.angle[p.rate_last[alarm]]), float(p.angle[p.rate_first[start]]))
        # river's own alarm must be the first step at which the statistic read from its state
        # exceeds the threshold (else the statistic we calibrated is not what river tests).
        before = max(up[:alarm].max(), down[:alarm].max()) if alarm > 0 else -math.inf
        out["pagehinkley_consistent"] = bool(max(up[alarm], down[alarm]) > ph_threshold >= before)
    t1 = clock()
    i, width = _adwin_run(p.z, adwin_delta, s)
    if i is not None:
        start = max(0, min(i - width + 1, p.z.size - 1))
        out["adwin"] = (float(p.angle[p.rate_last[i]]), float(p.angle[p.rate_first[start]]))
    secs.update({"pagehinkley": t1 - t0, "adwin": clock() - t1})
    return out


def check_linear_cost(args: tuple[PeerCurve, PeerSettings, int]) -> tuple[float, int, int]:
    """The prefix-sum cost against ruptures' CostLinear on random full-rank segments of one
    curve (largest relative difference), and Binseg's single break with each (equal or not)."""
    import ruptures as rpt

    curve, s, seed = args
    p = prepare(curve.angle, curve.torque, s)
    if p is None:
        return 0.0, 0, 0
    sig = np.column_stack((p.y, p.angle, np.ones(p.y.size)))
    fast = _make_linear_cost()(min_size=p.w).fit(sig)
    ref = rpt.costs.CostLinear().fit(sig)
    rng = np.random.default_rng(seed)
    worst = 0.0
    for _ in range(50):
        a, b = sorted(rng.choice(p.y.size + 1, size=2, replace=False))
        if b - a < p.w or np.ptp(p.angle[a:b]) == 0:
            continue
        r, f = ref.error(a, b), fast.error(a, b)
        worst = max(worst, abs(r - f) / max(abs(r), 1e-9))
    b_fast = rpt.Binseg(custom_cost=_make_linear_cost()(min_size=p.w), min_size=p.w, jump=5).fit(sig).predict(n_bkps=1)
    b_ref = rpt.Binseg(model="linear", min_size=p.w, jump=5).fit(sig).predict(n_bkps=1)
    return worst, 1, int(b_fast == b_ref)


# ---------------------------------------------------------------------------------------------


def pool_map(ex: ProcessPoolExecutor, fn: Callable[[Any], T], items: list[Any]) -> list[T]:
    chunk = max(1, len(items) // (8 * (ex._max_workers or 1)))  # type: ignore[attr-defined]
    return list(ex.map(fn, items, chunksize=chunk))


def calibrate_pelt(ex: ProcessPoolExecutor, curves: list[PeerCurve], s: PeerSettings, which: str, start: float) -> tuple[float, int, float]:
    """Smallest Pelt penalty at which at most 1 % of the calibration curves get a break.

    The number of breaks of the optimal penalised segmentation does not grow with the penalty,
    so a curve quiet at one penalty is quiet at every larger one and a curve that breaks at one
    penalty breaks at every smaller one: a bisection on log(penalty) only has to rerun Pelt on
    the curves that broke at the lower bracket and not at the upper one. Returns the penalty, the
    number of Pelt runs it took and their CPU seconds."""
    n = len(curves)
    allowed = int(math.floor(FA_TARGET * n))
    fired_lo: set[int] = set(range(n))  # at penalty lo (-> 0 every curve is assumed to break)
    fired_hi: set[int] = set()  # at penalty hi (-> inf no curve breaks)
    lo, hi = 0.0, math.inf
    pen = start
    runs, cpu = 0, 0.0
    for _ in range(40):
        todo = sorted(fired_lo - fired_hi)
        res = pool_map(ex, pelt_fires, [(curves[i], s, which, pen) for i in todo])
        runs += len(todo)
        cpu += sum(r[3] for r in res)
        fired = fired_hi | {i for i, r in zip(todo, res) if r[1]}
        if len(fired) > allowed:
            lo, fired_lo = pen, fired
        else:
            hi, fired_hi = pen, fired
        if math.isinf(hi):
            pen *= 2.0
        elif lo == 0.0:
            pen /= 2.0
        else:
            if hi / lo < 1.005 or len(fired_lo) - len(fired_hi) <= 0:
                break
            pen = math.sqrt(lo * hi)
    return hi, runs, cpu
