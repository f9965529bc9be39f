#!/usr/bin/env python3
"""Detection-quality benchmark: how well tightscan's detectors find friction changes, next to
off-the-shelf change-point methods given more help than ours get.

This is a benchmark, not a test: nothing fails. Every figure printed is measured in the run
that prints it, on curves simulated in that run (``tightscan.simulate``, seeded).

Data (all strategies CST/CSDT/HDT, all fault kinds abrupt/incipient/intermittent, all fault
components, |relative change of mu| uniform in 3-45 %; each set half without and half with the
clamp-force channel, the two halves with disjoint tightening ids so they are different curves):

- ``calibration``: clean curves (``fault_fraction=0``), seed ``SEED``. Only used to set
  thresholds at a 1 % false-alarm rate per curve.
- ``clean``: clean curves, seed ``SEED + 1``: the false-alarm rates reported (out of sample for
  every calibrated threshold, so they scatter around 1 %).
- ``faulty``: curves that all carry a fault (``fault_fraction=1``), seed ``SEED + 2``: recall,
  onset error, delay.

Our detectors (discovered from the result columns: a prefix ``X`` with ``X_alarm`` and
``X_change_angle`` or ``X_alarm_angle``; plus the decision rule ``change_detected`` /
``change_angle``) see the whole curve and find the elastic window themselves. They are scored at
their configured false-alarm rate and, where a continuous statistic exists (``X_p_value``,
``X_statistic``, ``X_max_statistic``), at a matched 1 % rate: the threshold exceeded by at most
1 % of the calibration curves. A tightening whose ``status`` is not ``ok`` counts as a miss.

Peers (ruptures Binseg/Pelt, river PageHinkley/ADWIN, statsmodels OLS-CUSUM) see only the TRUE
elastic zone from the truth table and are calibrated on the same calibration curves to 1 %.
They run on the first ``--peer-n`` curves of each set (a subsample: they are pure Python); our
detectors are also scored on exactly those curves, for a like-for-like comparison.

Figures go to stdout, ``benches/results/detection_quality.json`` and
``benches/results/recall_vs_magnitude.png``.

Usage: ``.venv/bin/python benches/detection_quality.py [--quick] [--n N] [--peer-n M] [--seed S]``
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import os
import platform
import resource
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Sequence, TypeVar

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc

import tightscan
from _benchutil import cpu_busy
from tightscan import _core

RESULTS = Path(__file__).resolve().parent / "results"
JSON_PATH = RESULTS / "detection_quality.json"
PLOT_PATH = RESULTS / "recall_vs_magnitude.png"

STRATEGIES = ("CST", "CSDT", "HDT")
FAULT_KINDS = ("abrupt", "incipient", "intermittent")
MAGNITUDE_RANGE = (0.03, 0.45)
# Bands of |magnitude| (relative change of mu); the last is closed on the right.
BANDS: tuple[tuple[float, float], ...] = ((0.03, 0.05), (0.05, 0.10), (0.10, 0.15), (0.15, 0.30), (0.30, 0.45))
SPLIT = 0.15  # "small" (< 15 %) and "large" (>= 15 %) changes, as the goals are stated
FA_TARGET = 0.01  # matched false-alarm rate per curve

# Goals of the detection-quality issue.
GOAL_FA = 0.01
GOAL_RECALL_LARGE = 0.99
GOAL_RECALL_SMALL = 0.88
GOAL_ONSET_ABRUPT_DEG = 0.5

# A detector whose angles are only reported when it alarms must be rerun at the matched
# threshold to give angles there: prefix -> the config key that sets its threshold in the units
# of its statistic (CUSUM h and the 3-sigma baseline's k, both in sigma). Used only if the key
# exists in the core's default config; the rerun's alarms are checked against the statistic.
MATCHED_RERUN_KEYS = {"cusum": "threshold", "shewhart": "shewhart_k"}

# Peers' window: samples recorded below this speed are left out. The slowest programmed speed
# of the simulated tools is 10 rpm (CSDT second step) and the speed channel's noise is 0.5 rpm,
# so this drops the CSDT pause (angle held while the torque relaxes: no torque-angle slope) and
# the last samples of the HDT coast-down, nothing else.
STOP_RPM = 5.0

SIM_CHUNK = 4000  # tightenings per simulate/detect call: bounds memory (~25 MB per 1,000)

T = TypeVar("T")


# ---------------------------------------------------------------------------------------------
# Simulation and our detectors


@dataclass(frozen=True)
class SetSpec:
    name: str
    seed: int
    n: int
    fault_fraction: float
    n_peer: int


@dataclass(frozen=True)
class OurDetector:
    """A detector discovered in the result columns."""

    name: str
    alarm: str
    angle: str  # change-start estimate if there is one, else the alarm angle
    alarm_angle: str | None
    candidates: tuple[tuple[str, float], ...]  # (column, sign) for the matched 1 % rate, in preference order
    statistic: str | None = None  # the candidate chosen on the calibration curves
    sign: float = 1.0  # +1: larger is more extreme; -1 (p-values): smaller is


def discover(columns: Sequence[str]) -> list[OurDetector]:
    """Every ``X`` with ``X_alarm`` and an angle column. Statistics for the matched rate, in
    order of preference: ``X_p_value`` (a test's own decision quantity, comparable between
    curves of different lengths, which raw statistics such as a sup-LR or a KDE distance are
    not), then ``X_statistic``, ``X_max_statistic`` and any other ``X_max_*`` (a maximum over
    the curve compared with a fixed threshold: CUSUM h, the 3-sigma baseline's k)."""
    cols = set(columns)
    found = []
    for c in columns:
        if not c.endswith("_alarm") or c == "_alarm":
            continue
        p = c[: -len("_alarm")]
        angle = next((a for a in (f"{p}_change_angle", f"{p}_alarm_angle") if a in cols), None)
        if angle is None:
            continue
        maxima = [m for m in columns if m.startswith(f"{p}_max_") and not m.endswith(("_index", "_angle"))]
        candidates = [(f"{p}_p_value", -1.0), (f"{p}_statistic", 1.0), (f"{p}_max_statistic", 1.0)] + [(m, 1.0) for m in maxima]
        usable = tuple((s, g) for s, g in dict.fromkeys(candidates) if s in cols)
        found.append(OurDetector(p, c, angle, f"{p}_alarm_angle" if f"{p}_alarm_angle" in cols else None, usable))
    return found


@dataclass
class PeerCurve:
    """What a peer is handed: one tightening's true elastic zone, angle and torque only."""

    row: int  # row in the set's frame
    angle: np.ndarray
    torque: np.ndarray


@dataclass
class SimulatedSet:
    spec: SetSpec
    frame: pd.DataFrame  # truth (``true_*``), our results, ``plant``
    peers: list[PeerCurve]
    seconds_simulate: float = 0.0
    seconds_detect: float = 0.0
    samples: int = 0


def _rows(chunk: int, n: int) -> Iterator[tuple[int, int]]:
    start = 0
    while start < n:
        yield start, min(chunk, n - start)
        start += chunk


def peer_windows(curves: pa.Table, truth: pa.Table, rows: Iterable[int], first_row: int) -> list[PeerCurve]:
    """The true elastic zone of each selected tightening: angle in [elastic_start_angle,
    final_angle] from the truth table, recorded speed >= STOP_RPM."""
    angle = curves.column("angle").combine_chunks()
    offsets = angle.offsets.to_numpy()
    a_all = angle.values.to_numpy(zero_copy_only=False)
    t_all = curves.column("torque").combine_chunks().values.to_numpy(zero_copy_only=False)
    s_all = curves.column("speed").combine_chunks().values.to_numpy(zero_copy_only=False)
    lo = truth.column("elastic_start_angle").to_numpy()
    hi = truth.column("final_angle").to_numpy()
    out = []
    for i in rows:
        s, e = offsets[i], offsets[i + 1]
        a = a_all[s:e].astype(np.float64)
        keep = (a >= lo[i]) & (a <= hi[i]) & (s_all[s:e] >= STOP_RPM)
        out.append(PeerCurve(first_row + i, a[keep], t_all[s:e][keep].astype(np.float64)))
    return out


def simulate_set(
    spec: SetSpec, config: dict[str, Any], detectors_reruns: dict[str, dict[str, Any]] | None,
    progress: Callable[[str], None],
) -> SimulatedSet:
    """Simulates a set in chunks (half without, half with clamp force), runs ``detect_batch``
    (``config``, and for each entry of ``detectors_reruns`` prefix -> config once more,
    keeping that prefix's columns as ``matched_<col>``), and cuts out the peers' windows of the
    first ``n_peer`` curves (half from each plant)."""
    frames: list[pd.DataFrame] = []
    peers: list[PeerCurve] = []
    sim_s = det_s = 0.0
    samples = 0
    row0 = 0
    halves = [(False, spec.n - spec.n // 2, spec.n_peer - spec.n_peer // 2), (True, spec.n // 2, spec.n_peer // 2)]
    first_id = 0
    for clamp, n_plant, n_peer in halves:
        for start, m in _rows(SIM_CHUNK, n_plant):
            t0 = time.perf_counter()
            curves, truth = tightscan.simulate(
                m,
                seed=spec.seed,
                fault_fraction=spec.fault_fraction,
                strategies=list(STRATEGIES),
                fault_kinds=list(FAULT_KINDS),
                magnitude_range=MAGNITUDE_RANGE,
                with_clamp_force=clamp,
                first_id=first_id + start,
            )
            t1 = time.perf_counter()
            res = tightscan.detect_batch(curves, config)
            reruns = {p: tightscan.detect_batch(curves, cfg) for p, cfg in (detectors_reruns or {}).items()}
            t2 = time.perf_counter()
            assert isinstance(res, pa.Table)
            sim_s += t1 - t0
            det_s += t2 - t1
            samples += int(pc.sum(truth.column("n_samples")).as_py())
            tf = truth.to_pandas().add_prefix("true_")
            rf = res.to_pandas()
            for p, rr in reruns.items():
                assert isinstance(rr, pa.Table)
                sub = rr.select([c for c in rr.column_names if c.startswith(f"{p}_")]).to_pandas()
                rf = pd.concat([rf, sub.add_prefix("matched_")], axis=1)
            f = pd.concat([tf, rf], axis=1)
            f["plant"] = "clamp_force" if clamp else "no_clamp_force"
            frames.append(f)
            sel = range(0, max(0, min(m, n_peer - start)))
            peers.extend(peer_windows(curves, truth, sel, row0))
            row0 += m
            del curves, truth, res, reruns
        first_id += n_plant
        progress(f"  {spec.name}: {'with' if clamp else 'without'} clamp force, {n_plant} curves")
    frame = pd.concat(frames, ignore_index=True)
    return SimulatedSet(spec, frame, peers, sim_s, det_s, samples)


# ---------------------------------------------------------------------------------------------
# Thresholds


def calibrate(values: np.ndarray, target: float = FA_TARGET) -> float:
    """The threshold exceeded by at most ``target`` of the calibration curves (alarm iff
    value > threshold; curves without a value hold -inf and never alarm)."""
    v = np.sort(np.asarray(values, dtype=np.float64))
    k = int(math.floor(target * v.size))
    return float(v[v.size - k - 1])


def stat_values(frame: pd.DataFrame, column: str, sign: float, ok: np.ndarray) -> np.ndarray:
    """The statistic oriented so that larger is more extreme; -inf where there is none."""
    raw = frame[column].to_numpy(dtype=np.float64, na_value=np.nan) * sign
    return np.asarray(np.where(ok & np.isfinite(raw), raw, -np.inf), dtype=np.float64)


def choose_statistic(frame: pd.DataFrame, det: OurDetector, ok: np.ndarray) -> tuple[OurDetector, float, list[dict[str, Any]]]:
    """The first candidate statistic fine enough to set a 1 % rate on the calibration curves:
    clipped or permutation p-values can tie at the threshold so that far fewer than 1 % exceed
    it; such a candidate (below half the target) gives way to the next. Returns the detector with
    its statistic set, the threshold and what was tried."""
    tried: list[dict[str, Any]] = []
    for column, sign in det.candidates:
        vals = stat_values(frame, column, sign, ok)
        thr = calibrate(vals)
        share = float((vals > thr).mean())
        tried.append({"column": column, "sign": sign, "threshold": thr, "calibration_exceedance": share})
        if share >= FA_TARGET / 2:
            return replace(det, statistic=column, sign=sign), thr, tried
    best = max(tried, key=lambda t: float(t["calibration_exceedance"]))
    return replace(det, statistic=best["column"], sign=best["sign"]), float(best["threshold"]), tried


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
# Scoring


@dataclass
class Outcome:
    """One detector at one operating point, on one evaluation subset.

    Arrays follow the rows of the clean and faulty frames restricted to ``subset``."""

    name: str
    family: str  # "ours", "decision", "peer"
    point: str  # "configured" or "matched 1 %"
    subset: str  # "all" or "peer"
    clean_alarm: np.ndarray
    clean_ran: np.ndarray
    fault_alarm: np.ndarray
    fault_ran: np.ndarray
    onset_est: np.ndarray  # change-start angle where the detector gives one (nan otherwise)
    alarm_angle: np.ndarray | None  # where it alarmed (streaming detectors), nan if none
    threshold: float | None = None
    note: str = ""


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    if n == 0:
        return (math.nan, math.nan)
    p = k / n
    den = 1 + z * z / n
    c = (p + z * z / (2 * n)) / den
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return (max(0.0, c - h), min(1.0, c + h))


def rate(mask: np.ndarray, sel: np.ndarray) -> dict[str, Any]:
    n = int(sel.sum())
    k = int((mask & sel).sum())
    lo, hi = wilson(k, n)
    return {"rate": k / n if n else None, "k": k, "n": n, "ci95": [lo, hi]}


def band_of(mag: np.ndarray, lo: float, hi: float, last: bool) -> np.ndarray:
    return (mag >= lo) & ((mag <= hi) if last else (mag < hi))


def score(o: Outcome, clean: pd.DataFrame, faulty: pd.DataFrame, groups: dict[str, tuple[np.ndarray, np.ndarray]] | None = None) -> dict[str, Any]:
    """All figures of one outcome. ``groups``: name -> (clean mask, faulty mask) for breakdowns."""
    mag = faulty["true_magnitude"].abs().to_numpy()
    kind = faulty["true_fault_kind"].to_numpy()
    sign = np.sign(faulty["true_magnitude"].to_numpy())
    onset = faulty["true_onset_angle"].to_numpy()
    every = np.ones(len(faulty), dtype=bool)

    def block(csel: np.ndarray, fsel: np.ndarray) -> dict[str, Any]:
        det = o.fault_alarm
        r: dict[str, Any] = {
            "false_alarm": rate(o.clean_alarm, csel),
            "not_run_clean": rate(~o.clean_ran, csel)["rate"],
            "not_run_faulty": rate(~o.fault_ran, fsel)["rate"],
            "recall": rate(det, fsel),
            "recall_lt15": rate(det, fsel & (mag < SPLIT)),
            "recall_ge15": rate(det, fsel & (mag >= SPLIT)),
            "recall_by_kind": {k: rate(det, fsel & (kind == k)) for k in FAULT_KINDS},
            # By direction: a large increase can end the tightening right after the onset.
            "recall_by_sign": {"increase": rate(det, fsel & (sign > 0)), "decrease": rate(det, fsel & (sign < 0))},
            "recall_by_band": {
                f"{lo * 100:g}-{hi * 100:g}%": rate(det, fsel & band_of(mag, lo, hi, j == len(BANDS) - 1))
                for j, (lo, hi) in enumerate(BANDS)
            },
        }
        err = np.abs(o.onset_est - onset)
        has = det & fsel & np.isfinite(err)
        ab = has & (kind == "abrupt")
        r["onset_abs_err_median_abrupt_deg"] = float(np.median(err[ab])) if ab.any() else None
        r["onset_abs_err_median_all_deg"] = float(np.median(err[has])) if has.any() else None
        r["onset_n_abrupt"] = int(ab.sum())
        r["onset_n_all"] = int(has.sum())
        r["onset_coverage"] = float(has.sum() / max(int((det & fsel).sum()), 1))
        if o.alarm_angle is not None:
            d = o.alarm_angle - onset
            hd = det & fsel & np.isfinite(d)
            r["delay_median_deg"] = float(np.median(d[hd])) if hd.any() else None
            r["delay_median_abrupt_deg"] = float(np.median(d[hd & (kind == "abrupt")])) if (hd & (kind == "abrupt")).any() else None
            # Alarms before the change began: counted as detections above, shown here.
            r["alarm_before_onset_share"] = float((d[hd] < 0).mean()) if hd.any() else None
        else:
            r["delay_median_deg"] = r["delay_median_abrupt_deg"] = r["alarm_before_onset_share"] = None
        return r

    out = {"name": o.name, "family": o.family, "point": o.point, "subset": o.subset,
           "threshold": o.threshold, "note": o.note, **block(np.ones(len(clean), dtype=bool), every)}
    if groups:
        out["groups"] = {g: block(c, f) for g, (c, f) in groups.items()}
    return out


def recall_curve(o: Outcome, faulty: pd.DataFrame, edges: np.ndarray) -> list[float | None]:
    mag = faulty["true_magnitude"].abs().to_numpy()
    vals: list[float | None] = []
    for j in range(edges.size - 1):
        sel = band_of(mag, edges[j], edges[j + 1], j == edges.size - 2)
        vals.append(float(o.fault_alarm[sel].mean()) if sel.any() else None)
    return vals


# ---------------------------------------------------------------------------------------------
# Output


def pct(x: float | None, digits: int = 1) -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{100 * x:.{digits}f}"


def deg(x: float | None) -> str:
    return "-" if x is None else f"{x:.2f}"


def print_tables(console: Any, title: str, scores: list[dict[str, Any]]) -> None:
    from rich.table import Table

    t = Table(title=f"{title}: false alarms and recall [%] by |change of mu|", title_justify="left")
    for c in ["detector", "point", "FA clean", "3-5", "5-10", "10-15", "15-30", "30-45", "<15", ">=15", "all"]:
        t.add_column(c, justify="left" if c in ("detector", "point") else "right")
    for s in scores:
        t.add_row(s["name"], s["point"], pct(s["false_alarm"]["rate"], 2),
                  *[pct(v["rate"]) for v in s["recall_by_band"].values()],
                  pct(s["recall_lt15"]["rate"]), pct(s["recall_ge15"]["rate"]), pct(s["recall"]["rate"]))
    console.print(t)
    t = Table(title=f"{title}: recall by kind [%], onset error and delay [deg] (medians over detected faults)",
              title_justify="left")
    for c in ["detector", "point", "abrupt", "incip.", "interm.", "mu up", "mu down", "|onset err| abrupt", "|onset err| all",
              "delay", "alarm<onset %", "not run %"]:
        t.add_column(c, justify="left" if c in ("detector", "point") else "right")
    for s in scores:
        t.add_row(s["name"], s["point"], *[pct(v["rate"]) for v in s["recall_by_kind"].values()],
                  *[pct(v["rate"]) for v in s["recall_by_sign"].values()],
                  deg(s["onset_abs_err_median_abrupt_deg"]), deg(s["onset_abs_err_median_all_deg"]),
                  deg(s["delay_median_deg"]), pct(s["alarm_before_onset_share"]), pct(s["not_run_faulty"]))
    console.print(t)


def print_groups(console: Any, scores: list[dict[str, Any]]) -> None:
    from rich.table import Table

    t = Table(title="Ours by strategy and plant (all curves)", title_justify="left")
    for c in ["detector", "point", "group", "FA %", "recall <15 %", "recall >=15 %", "|onset err| abrupt", "not ok %", "n clean", "n faulty"]:
        t.add_column(c, justify="left" if c in ("detector", "point", "group") else "right")
    for s in scores:
        for g, r in s.get("groups", {}).items():
            t.add_row(s["name"], s["point"], g, pct(r["false_alarm"]["rate"], 2), pct(r["recall_lt15"]["rate"]),
                      pct(r["recall_ge15"]["rate"]), deg(r["onset_abs_err_median_abrupt_deg"]),
                      pct(r["not_run_faulty"]), str(r["false_alarm"]["n"]), str(r["recall"]["n"]))
    console.print(t)


def plot(path: Path, panels: list[tuple[str, list[Outcome], pd.DataFrame]], edges: np.ndarray) -> None:
    """Recall per 3 %-wide bin of |magnitude|; one colour per detector in every panel, ours as
    thick solid lines, peers dashed, anything not at the matched rate dotted."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(dict.fromkeys(o.name for _, items, _ in panels for o in items))
    # tab20 comes in dark/light pairs: the ten dark hues first, then the light ones.
    cmap = plt.get_cmap("tab20")
    order = list(range(0, 20, 2)) + list(range(1, 20, 2))
    colour = {name: cmap(order[i % 20]) for i, name in enumerate(names)}
    markers = "osD^v<>phX*"
    centres = 100 * 0.5 * (edges[1:] + edges[:-1])
    fig, axes = plt.subplots(1, len(panels), figsize=(7.5 * len(panels), 5.4), sharey=True)
    for ax, (title, items, faulty) in zip(np.atleast_1d(axes), panels):
        for o in items:
            ys = [np.nan if v is None else v for v in recall_curve(o, faulty, edges)]
            matched = o.point.startswith("matched")
            ours = o.family != "peer"
            ax.plot(centres, ys, "-" if ours and matched else (":" if not matched else "--"),
                    color=colour[o.name], lw=2.2 if ours else 1.3, marker=markers[names.index(o.name) % len(markers)],
                    ms=3.5, label=o.name + ("" if matched else f" ({o.point})") + ("" if ours else " [peer]"))
        for g, ls in ((GOAL_RECALL_LARGE, ":"), (GOAL_RECALL_SMALL, "--")):
            ax.axhline(g, color="grey", lw=0.8, ls=ls)
        ax.axvline(100 * SPLIT, color="grey", lw=0.8)
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("|relative change of mu| [%]")
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="lower right", ncol=2)
    np.atleast_1d(axes)[0].set_ylabel("recall (not-ok rows count as misses)")
    fig.suptitle("Recall against the size of the friction change at a matched 1 % false-alarm rate per curve "
                 "(grey: goals 0.99 for >= 15 %, 0.88 below)", fontsize=11)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=130)
    plt.close(fig)


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


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=None, help="faulty curves, and clean curves per clean set, for our detectors (default 20000; --quick 4000)")
    ap.add_argument("--peer-n", type=int, default=None, help="curves per set handed to the peers (default 3000; --quick 300)")
    ap.add_argument("--quick", action="store_true", help="small sizes (about 1-2 minutes)")
    ap.add_argument("--seed", type=int, default=20261122, help="calibration seed; +1 clean evaluation, +2 faulty")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="processes for the peers")
    ap.add_argument("--pelt-jump", type=int, default=5, help="Pelt's grid step in samples (ruptures' default 5)")
    ap.add_argument("--json", type=Path, default=JSON_PATH)
    ap.add_argument("--plot", type=Path, default=PLOT_PATH)
    args = ap.parse_args()
    n = args.n if args.n is not None else (4000 if args.quick else 20000)
    n_peer = min(n, args.peer_n if args.peer_n is not None else (300 if args.quick else 3000))

    from rich.console import Console

    # No markup: the text holds [brackets] (intervals, lists) that rich would read as tags.
    console = Console(width=200, markup=False, highlight=False)
    started = time.perf_counter()
    stages: dict[str, float] = {}

    def say(msg: str) -> None:
        console.print(f"[{time.perf_counter() - started:6.1f} s] {msg}", highlight=False)

    if _core.DEBUG_BUILD:
        console.print("warning: tightscan._core is a debug build")
    busy_before = cpu_busy()
    if busy_before is not None and busy_before > 0.10:
        console.print(f"warning: {busy_before:.0%} of the CPUs were busy before the run: wall times will be long "
                      f"(the CPU times printed at the end are not affected)")
    defaults = _core.default_config()
    settings = PeerSettings(
        min_samples=int(defaults["zone_min_samples"]), max_windows=int(defaults["max_blocks"]),
        min_window=int(defaults["min_block_samples"]), burn_in=int(defaults["min_training_blocks"]),
        ph_delta=float(defaults["kappa"]), pelt_jump=args.pelt_jump,
    )
    specs = {
        "calibration": SetSpec("calibration", args.seed, n, 0.0, n_peer),
        "clean": SetSpec("clean", args.seed + 1, n, 0.0, n_peer),
        "faulty": SetSpec("faulty", args.seed + 2, n, 1.0, n_peer),
    }

    # --- our detectors: calibration set, then matched thresholds, then evaluation sets --------
    # Opt-in detectors (a boolean config key named like a detector, off by default, e.g. the
    # KDE test) are switched on: the benchmark measures every detector there is. Everything
    # else stays at the core's defaults.
    probe = tightscan.detect_batch(tightscan.simulate(20, seed=args.seed)[0])
    assert isinstance(probe, pa.Table)
    opt_in = {d.name: True for d in discover(probe.column_names) if defaults.get(d.name) is False}
    run_config = {**defaults, **opt_in}
    say(f"simulating and detecting: {n} curves per set, peers on the first {n_peer} of each"
        + (f"; opt-in detectors switched on: {', '.join(opt_in)}" if opt_in else ""))
    cal = simulate_set(specs["calibration"], run_config, None, say)
    ok_cal = (cal.frame["status"] == "ok").to_numpy()
    matched_thr: dict[str, float] = {}
    statistic_choice: dict[str, list[dict[str, Any]]] = {}
    reruns: dict[str, dict[str, Any]] = {}
    dets: list[OurDetector] = []
    for d in discover(list(cal.frame.columns)):
        if not d.candidates:
            dets.append(d)
            continue
        d, matched_thr[d.name], statistic_choice[d.name] = choose_statistic(cal.frame, d, ok_cal)
        dets.append(d)
        key = MATCHED_RERUN_KEYS.get(d.name)
        if key in defaults and d.sign > 0:
            # The opt-in detectors are off in a rerun: it only serves this detector's columns.
            reruns[d.name] = {**run_config, **{k: False for k in opt_in}, key: matched_thr[d.name]}
    clean = simulate_set(specs["clean"], run_config, reruns, say)
    faulty = simulate_set(specs["faulty"], run_config, reruns, say)
    stages["simulate_s"] = cal.seconds_simulate + clean.seconds_simulate + faulty.seconds_simulate
    stages["detect_batch_s"] = cal.seconds_detect + clean.seconds_detect + faulty.seconds_detect
    stages["ours_total_s"] = time.perf_counter() - started

    cf, ff = clean.frame, faulty.frame
    ok_c, ok_f = (cf["status"] == "ok").to_numpy(), (ff["status"] == "ok").to_numpy()

    def col(frame: pd.DataFrame, name: str | None) -> np.ndarray:
        if name is None or name not in frame:
            return np.full(len(frame), np.nan)
        return np.asarray(frame[name].to_numpy(dtype=np.float64, na_value=np.nan), dtype=np.float64)

    def flag(frame: pd.DataFrame, name: str, ok: np.ndarray) -> np.ndarray:
        return np.asarray(ok & frame[name].fillna(False).to_numpy(dtype=bool), dtype=bool)

    ours: list[Outcome] = []
    rerun_agreement: dict[str, float] = {}
    for d in dets:
        ours.append(Outcome(d.name, "ours", "configured", "all", flag(cf, d.alarm, ok_c), ok_c, flag(ff, d.alarm, ok_f),
                            ok_f, col(ff, d.angle), col(ff, d.alarm_angle) if d.alarm_angle else None))
        if d.name not in matched_thr:
            continue
        thr = matched_thr[d.name]
        assert d.statistic is not None
        ca = stat_values(cf, d.statistic, d.sign, ok_c) > thr
        fa = stat_values(ff, d.statistic, d.sign, ok_f) > thr
        note = f"alarm iff {d.statistic} < {-thr:.4g}" if d.sign < 0 else f"alarm iff {d.statistic} > {thr:.4g}"
        if d.name in reruns:
            # Angles from the rerun at the matched threshold; its alarms must be the same as
            # thresholding the statistic (checked, reported).
            m_alarm = flag(ff, f"matched_{d.alarm}", ok_f)
            rerun_agreement[d.name] = float((m_alarm == fa).mean())
            onset = np.where(fa, col(ff, f"matched_{d.angle}"), np.nan)
            alarm_at = np.where(fa, col(ff, f"matched_{d.alarm_angle}"), np.nan) if d.alarm_angle else None
            note += f"; rerun with config {MATCHED_RERUN_KEYS[d.name]}={thr:.4g}"
        else:
            # No rerun. A change-angle estimate of the configured run is used where that run
            # reports one (break: on every analysed row; kde: only where it alarmed, so part of
            # the matched alarms have none: the coverage is in the JSON). An alarm angle depends
            # on the threshold (the first crossing of another threshold is elsewhere), so it is
            # left out: "-" in the tables.
            alarm_at = None
            if d.angle != d.alarm_angle:
                onset = np.where(fa, col(ff, d.angle), np.nan)
                covered = int((fa & np.isfinite(onset)).sum())
                note += f"; change angles of the configured run, available for {covered} of {int(fa.sum())} matched faulty alarms"
            else:
                onset = np.full(len(ff), np.nan)
                note += "; angles n/a at this rate (only an alarm angle, which depends on the threshold; no config key to rerun with)"
        ours.append(Outcome(d.name, "ours", "matched 1 %", "all", ca, ok_c, fa, ok_f, onset, alarm_at, thr * d.sign, note))
    decision = Outcome("decision rule", "decision", "configured", "all", flag(cf, "change_detected", ok_c), ok_c,
                       flag(ff, "change_detected", ok_f), ok_f, col(ff, "change_angle"),
                       col(ff, "alarm_angle") if "alarm_angle" in ff else None)
    ours.append(decision)

    # --- peers ----------------------------------------------------------------------------------
    say(f"peers: statistics on {len(cal.peers)} + {len(clean.peers)} + {len(faulty.peers)} curves, {args.workers} processes")
    t_peers = time.perf_counter()
    peer_names = ["binseg_linear", "pelt_linear", "binseg_l2_rate", "pelt_l2_rate", "pagehinkley", "adwin", "ols_cusum"]
    ctx = mp.get_context("spawn")  # the parent holds rayon threads: do not fork it
    # One BLAS thread per worker: the workers already fill the cores, and idle BLAS threads
    # spinning on small lstsq calls would only compete with them. (Read when a worker imports
    # numpy; the parent's numpy is already loaded and unaffected.)
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    with ProcessPoolExecutor(max_workers=args.workers, mp_context=ctx) as ex:
        stats_by_set = {name: pool_map(ex, peer_statistics, [(c, settings) for c in st.peers])
                        for name, st in (("calibration", cal), ("clean", clean), ("faulty", faulty))}
        checks = pool_map(ex, check_linear_cost, [(c, settings, i) for i, c in enumerate(cal.peers[:40])])
        stages["peers_statistics_s"] = time.perf_counter() - t_peers
        say("peers: calibrating")

        def peer_stat(rows: list[dict[str, Any]], name: str) -> np.ndarray:
            v = [r.get(name) for r in rows]
            return np.array([-np.inf if x is None else (x[0] if isinstance(x, tuple) else x) for x in v], dtype=np.float64)

        thr_peer = {k: calibrate(peer_stat(stats_by_set["calibration"], k)) for k in
                    ("binseg_linear", "binseg_l2_rate", "pagehinkley", "adwin", "ols_cusum")}
        t0 = time.perf_counter()
        pelt_pen: dict[str, float] = {}
        pelt_runs: dict[str, int] = {}
        cpu: dict[str, float] = {k: 0.0 for k in peer_names + ["prepare"]}  # CPU seconds per peer
        calls: dict[str, int] = {k: 0 for k in peer_names}  # runs of each peer on one curve
        for rows in stats_by_set.values():
            for r in rows:
                for k, v in r["seconds"].items():
                    cpu[k] += v
                    calls[k] = calls.get(k, 0) + (k != "prepare")
        for which, seed_stat in (("pelt_linear", "binseg_linear"), ("pelt_l2_rate", "binseg_l2_rate")):
            # Start below the single-break threshold (the penalty at which a curve stays quiet is
            # at least about its best single-break gain), so that the bisection mostly climbs
            # and reruns only the few curves that still break.
            pelt_pen[which], pelt_runs[which], c = calibrate_pelt(ex, cal.peers, settings, which, 0.5 * thr_peer[seed_stat])
            cpu[which] += c
            calls[which] += pelt_runs[which]
        stages["peers_pelt_calibration_s"] = time.perf_counter() - t0
        say("peers: evaluating at the calibrated settings")
        t0 = time.perf_counter()
        adwin_delta = 10.0 ** (-thr_peer["adwin"]) if math.isfinite(thr_peer["adwin"]) else 10.0 ** ADWIN_LOG10_RANGE[1]
        evals: dict[str, dict[str, Any]] = {}
        for name, st in (("clean", clean), ("faulty", faulty)):
            e: dict[str, Any] = {}
            for which in ("pelt_linear", "pelt_l2_rate"):
                e[which] = pool_map(ex, pelt_fires, [(c, settings, which, pelt_pen[which]) for c in st.peers])
            e["stream"] = pool_map(ex, peer_streaming, [(c, settings, thr_peer["pagehinkley"], adwin_delta) for c in st.peers])
            evals[name] = e
            for which in ("pelt_linear", "pelt_l2_rate"):
                cpu[which] += sum(r[3] for r in e[which])
                calls[which] += len(e[which])
            for r in e["stream"]:
                for k, v in r["seconds"].items():
                    cpu[k] += v
                    calls[k] = calls.get(k, 0) + (k != "prepare")
        stages["peers_evaluation_s"] = time.perf_counter() - t0
    stages["peers_total_s"] = time.perf_counter() - t_peers

    # Peer outcomes on the peer rows of the clean and faulty sets.
    prow_c = np.array([c.row for c in clean.peers], dtype=np.int64)
    prow_f = np.array([c.row for c in faulty.peers], dtype=np.int64)
    cfp, ffp = cf.iloc[prow_c].reset_index(drop=True), ff.iloc[prow_f].reset_index(drop=True)
    ran_c = np.array([r["ran"] for r in stats_by_set["clean"]])
    ran_f = np.array([r["ran"] for r in stats_by_set["faulty"]])
    onset_truth = ffp["true_onset_angle"].to_numpy()
    nan_f = np.full(len(ffp), np.nan)
    peers: list[Outcome] = []
    what_peers_get = (
        "samples with angle in [truth.elastic_start_angle, truth.final_angle] and recorded speed >= "
        f"{STOP_RPM:g} rpm (drops the CSDT pause and the end of the HDT coast)"
    )
    for k in ("binseg_linear", "binseg_l2_rate", "ols_cusum"):
        thr = thr_peer[k]
        sc, sf = peer_stat(stats_by_set["clean"], k), peer_stat(stats_by_set["faulty"], k)
        loc = np.array([r[k][1] if k in r else np.nan for r in stats_by_set["faulty"]])
        fa = sf > thr
        note = {"binseg_linear": f"Binseg(linear cost: torque ~ [angle, 1]), n_bkps=1, jump 1; alarm iff cost reduction > {thr:.4g}",
                "binseg_l2_rate": f"Binseg(l2) on the local torque rate, n_bkps=1, jump 1; alarm iff cost reduction > {thr:.4g}",
                "ols_cusum": f"breaks_cusumolsresid(ddof=2) on OLS residuals torque ~ angle; alarm iff p < {10 ** -thr:.3g}"}[k]
        peers.append(Outcome(k, "peer", "matched 1 %", "peer", sc > thr, ran_c, fa, ran_f, np.where(fa, loc, np.nan), None, thr, note))
    for k in ("pelt_linear", "pelt_l2_rate"):
        rc, rf = evals["clean"][k], evals["faulty"][k]
        fa = np.array([r[1] for r in rf], dtype=bool)
        note = (f"Pelt({'linear cost, min_size = rate window, jump ' + str(settings.pelt_jump) if k == 'pelt_linear' else 'l2 on the torque rate, jump 1'}), "
                f"penalty {pelt_pen[k]:.4g} ({pelt_runs[k]} Pelt runs to calibrate); onset = first break")
        peers.append(Outcome(k, "peer", "matched 1 %", "peer", np.array([r[1] for r in rc], dtype=bool), ran_c, fa, ran_f,
                             np.array([r[2] for r in rf]), None, pelt_pen[k], note))
    for k in ("pagehinkley", "adwin"):
        sc_ = [k in r for r in evals["clean"]["stream"]]
        sf_ = evals["faulty"]["stream"]
        fa = np.array([k in r for r in sf_], dtype=bool)
        alarm_at = np.array([r[k][0] if k in r else np.nan for r in sf_])
        onset_est = np.array([r[k][1] if k in r else np.nan for r in sf_])
        note = (f"river PageHinkley(delta={settings.ph_delta:g}, min_instances={settings.burn_in}), threshold {thr_peer[k]:.4g}"
                if k == "pagehinkley" else
                f"river ADWIN(clock=1, grace_period={settings.burn_in}), delta {adwin_delta:.3g}")
        peers.append(Outcome(k, "peer", "matched 1 %", "peer", np.array(sc_, dtype=bool), ran_c, fa, ran_f, onset_est, alarm_at,
                             thr_peer[k] if k == "pagehinkley" else adwin_delta, note))
    ph_consistent = [r["pagehinkley_consistent"] for r in evals["faulty"]["stream"] + evals["clean"]["stream"] if "pagehinkley_consistent" in r]

    # Ours restricted to the peers' curves.
    def restrict(o: Outcome) -> Outcome:
        return Outcome(o.name, o.family, o.point, "peer", o.clean_alarm[prow_c], o.clean_ran[prow_c], o.fault_alarm[prow_f],
                       o.fault_ran[prow_f], o.onset_est[prow_f], None if o.alarm_angle is None else o.alarm_angle[prow_f],
                       o.threshold, o.note)

    same_curves = [restrict(o) for o in ours] + peers
    groups: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for s_ in STRATEGIES:
        groups[s_] = ((cf["true_strategy"] == s_).to_numpy(), (ff["true_strategy"] == s_).to_numpy())
    for p_ in ("no_clamp_force", "clamp_force"):
        groups[p_] = ((cf["plant"] == p_).to_numpy(), (ff["plant"] == p_).to_numpy())
    scores_same = [score(o, cfp, ffp) for o in same_curves]
    scores_all = [score(o, cf, ff, groups) for o in ours]

    # --- print ------------------------------------------------------------------------------------
    stages["total_s"] = time.perf_counter() - started
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    stages["cpu_main_process_s"] = own.ru_utime + own.ru_stime
    stages["cpu_peer_processes_s"] = kids.ru_utime + kids.ru_stime
    console.rule("tightscan detection-quality benchmark")
    status_counts = {name: {str(k): int(v) for k, v in st.frame["status"].str.split(":").str[0].value_counts().items()}
                     for name, st in (("calibration", cal), ("clean", clean), ("faulty", faulty))}
    console.print(
        f"curves: {n} per set (calibration seed {specs['calibration'].seed}, clean seed {specs['clean'].seed}, faulty seed "
        f"{specs['faulty'].seed}); each set half without / half with clamp force; strategies {', '.join(STRATEGIES)}; "
        f"kinds {', '.join(FAULT_KINDS)}; |change of mu| uniform {MAGNITUDE_RANGE[0]:.0%}-{MAGNITUDE_RANGE[1]:.0%}.\n"
        f"statuses: {status_counts}\n"
        f"Thresholds are set on the calibration curves (1 % = at most {int(FA_TARGET * n)} of {n} for ours, "
        f"{int(FA_TARGET * n_peer)} of {n_peer} for peers); false alarms are counted on the other clean set.\n"
        f"OURS run with the default config{' plus ' + ', '.join(f'{k}=True' for k in opt_in) if opt_in else ''} (configured "
        f"rate = that config); they get the whole curve and find the elastic window themselves; rows whose status is not ok count as misses "
        f"(and never as false alarms).\n"
        f"PEERS get the TRUE elastic zone: {what_peers_get}; torque divided by a noise scale estimated from the window; "
        f"the local torque rate is the least-squares slope of windows of max({settings.min_window}, ceil(n/{settings.max_windows})) "
        f"samples, divided by a robust scale (MAD of its differences / sqrt 2). Peers run on the first {n_peer} curves of each "
        f"set (subsample; pure Python), ours on all {n}. A peer does not run on a window of < {settings.min_samples} samples "
        f"(counted as a miss).",
        highlight=False,
    )
    for s in scores_same:
        if s["note"]:
            console.print(f"  {s['name']} ({s['point']}): {s['note']}", highlight=False)
    worst_cost, n_chk, same_bkp = max((c[0] for c in checks), default=0.0), sum(c[1] for c in checks), sum(c[2] for c in checks)
    console.print(f"checks: prefix-sum linear cost vs ruptures CostLinear on {n_chk} curves: max rel. difference "
                  f"{worst_cost:.1e}, same Binseg break (jump 5) on {same_bkp}/{n_chk}; "
                  + (", ".join(f"{k} rerun alarms = statistic > threshold on {v:.2%} of faulty rows" for k, v in rerun_agreement.items()) or "no reruns")
                  + f"; river PageHinkley alarm = first statistic > threshold on {sum(ph_consistent)}/{len(ph_consistent)} alarms",
                  highlight=False)
    # Where our misses come from: the change outside the window the detector analysed (e.g. a
    # large increase of mu makes the torque jump to the target at the onset, so the window,
    # which ends at a fraction of the rise, ends there too) or not.
    onset_f = ff["true_onset_angle"].to_numpy()
    outside = ok_f & (onset_f > col(ff, "elastic_end_angle"))
    miss_info = {}
    for o in ours:
        if o.point != "configured":
            continue
        missed_ok = ok_f & ~o.fault_alarm
        miss_info[o.name] = {"missed_ok": int(missed_ok.sum()), "onset_beyond_window": int((missed_ok & outside).sum()),
                             "not_ok": int((~ok_f).sum())}
    console.print("misses of ours (configured): " + "; ".join(
        f"{k}: {v['not_ok']} not ok + {v['missed_ok']} ok, of which {v['onset_beyond_window']} with the true onset "
        f"beyond elastic_end_angle" for k, v in miss_info.items())
        + f" (onset beyond the window on {outside.sum()} of {ok_f.sum()} ok faulty rows)", highlight=False)
    fired_summary: dict[str, dict[str, int]] = {}
    if "detectors_fired" in ff:
        # Which detectors make up the decision rule's alarms (false ones on the clean set).
        for name, frame, ok in (("clean", cf, ok_c), ("faulty", ff, ok_f)):
            alarmed = ok & frame["change_detected"].fillna(False).to_numpy(dtype=bool)
            counts = frame.loc[alarmed, "detectors_fired"].astype(str).value_counts()
            fired_summary[name] = {str(k): int(v) for k, v in counts.items()}
        console.print("decision rule alarms by detectors_fired: " + "; ".join(
            f"{name}: " + ", ".join(f"{k or '(none)'} {v}" for k, v in list(c.items())[:6]) for name, c in fired_summary.items()),
            highlight=False)
    print_tables(console, f"Same curves ({n_peer} clean, {n_peer} faulty): ours vs peers", scores_same)
    print_tables(console, f"Ours on all curves ({n} clean, {n} faulty)", scores_all)
    print_groups(console, scores_all)

    from rich.table import Table

    goals_out: list[dict[str, Any]] = []
    t = Table(title="Goals of the issue (ours on all curves)", title_justify="left")
    for header in ["detector", "point", f"FA <= {GOAL_FA:.0%}", f"recall >=15 % >= {GOAL_RECALL_LARGE}",
                   f"recall 3-15 % >= {GOAL_RECALL_SMALL}", f"|onset err| abrupt <= {GOAL_ONSET_ABRUPT_DEG} deg"]:
        t.add_column(header)
    for s in scores_all:
        fa = s["false_alarm"]["rate"]
        rl, rs = s["recall_ge15"]["rate"], s["recall_lt15"]["rate"]
        oe = s["onset_abs_err_median_abrupt_deg"]
        g = {
            "fa": (fa is not None and fa <= GOAL_FA, f"{pct(fa, 3)} % [{pct(s['false_alarm']['ci95'][0], 2)}, {pct(s['false_alarm']['ci95'][1], 2)}]"),
            "recall_ge15": (rl is not None and rl >= GOAL_RECALL_LARGE, f"{pct(rl, 2)} % [{pct(s['recall_ge15']['ci95'][0])}, {pct(s['recall_ge15']['ci95'][1])}]"),
            "recall_lt15": (rs is not None and rs >= GOAL_RECALL_SMALL, f"{pct(rs, 2)} % [{pct(s['recall_lt15']['ci95'][0])}, {pct(s['recall_lt15']['ci95'][1])}]"),
            "onset_abrupt": (oe is not None and oe <= GOAL_ONSET_ABRUPT_DEG, deg(oe)),
        }
        goals_out.append({"name": s["name"], "point": s["point"], **{k: {"met": v[0], "value": v[1]} for k, v in g.items()}})
        t.add_row(s["name"], s["point"], *[("met  " if m else "MISSED ") + v for m, v in g.values()])
    console.print(t)
    console.print("(values with 95 % Wilson intervals; FA is the out-of-sample rate on the clean set)", highlight=False)
    console.print(
        f"runtime: total {stages['total_s']:.1f} s; simulate {stages['simulate_s']:.1f} s, detect_batch {stages['detect_batch_s']:.1f} s "
        f"(default config{' + matched reruns' if reruns else ''}; {(cal.samples + clean.samples + faulty.samples) / 1e6:.0f} M samples), "
        f"peers {stages['peers_total_s']:.1f} s wall (statistics {stages['peers_statistics_s']:.1f}, Pelt calibration "
        f"{stages['peers_pelt_calibration_s']:.1f}, evaluation {stages['peers_evaluation_s']:.1f}) on {args.workers} processes; "
        f"CPU time: main process {stages['cpu_main_process_s']:.1f} s, peer processes {stages['cpu_peer_processes_s']:.1f} s"
        + (f"; {busy_before:.0%} of the CPUs were busy with other work just before the run" if busy_before is not None else ""),
        highlight=False,
    )
    console.print("peer CPU per run on one curve [ms]: " + ", ".join(
        f"{k} {1e3 * cpu[k] / max(calls[k], 1):.1f} ({calls[k]} runs)" for k in peer_names)
        + f"; shared preprocessing {1e3 * cpu['prepare']:.0f} ms in all", highlight=False)

    # --- save -------------------------------------------------------------------------------------
    edges = np.round(np.arange(MAGNITUDE_RANGE[0], MAGNITUDE_RANGE[1] + 1e-9, 0.03), 4)
    panel_same = [o for o in (restrict(o) for o in ours) if o.point.startswith("matched")] + peers
    panel_all = [o for o in ours if o.point.startswith("matched")] + [decision]
    plot(args.plot, [(f"same {n_peer} faulty curves: ours (whole curve) vs peers (true elastic zone)", panel_same, ffp),
                     (f"ours on all {n} faulty curves (decision rule at its configured rate)", panel_all, ff)], edges)
    record = {
        "timestamp": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "args": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
        "n_per_set": n, "n_peer_per_set": n_peer,
        "seeds": {k: v.seed for k, v in specs.items()},
        "magnitude_range": MAGNITUDE_RANGE, "bands": BANDS, "fa_target": FA_TARGET,
        "status_counts": status_counts,
        "detectors_discovered": [d.__dict__ for d in dets],
        "opt_in_switched_on": list(opt_in),
        # in the statistic's own units (p-values: alarm below it; the others: alarm above it)
        "matched_thresholds_ours": {d.name: matched_thr[d.name] * d.sign for d in dets if d.name in matched_thr},
        "matched_statistic_choice": statistic_choice,
        # in each peer's own units
        "peer_thresholds": {
            "binseg_linear_cost_reduction": thr_peer["binseg_linear"],
            "binseg_l2_rate_cost_reduction": thr_peer["binseg_l2_rate"],
            "pagehinkley_threshold": thr_peer["pagehinkley"],
            "adwin_delta": adwin_delta,
            "ols_cusum_p_value": 10.0 ** -thr_peer["ols_cusum"],
            **{f"{k}_penalty": v for k, v in pelt_pen.items()},
        },
        "peer_input": what_peers_get,
        "peer_settings": settings.__dict__,
        "checks": {"linear_cost_max_rel_diff": worst_cost, "linear_cost_curves": n_chk, "binseg_same_break": same_bkp,
                   "rerun_agreement": rerun_agreement, "pagehinkley_consistent": [sum(ph_consistent), len(ph_consistent)]},
        "same_curves": scores_same,
        "ours_all_curves": scores_all,
        "recall_vs_magnitude": {"edges": edges.tolist(),
                                "same_curves": {f"{o.name} ({o.point})": recall_curve(o, ffp, edges) for o in panel_same},
                                "ours_all_curves": {f"{o.name} ({o.point})": recall_curve(o, ff, edges) for o in panel_all}},
        "goals": goals_out,
        "misses_of_ours": miss_info,
        "decision_rule_detectors_fired": fired_summary,
        "config_ours": {k: v for k, v in run_config.items()},
        "tightscan_core": {"file": _core.__file__, "mtime": time.strftime("%Y-%m-%dT%H:%M:%S%z", time.localtime(os.path.getmtime(_core.__file__)))},
        "runtime_s": stages,
        "cpu_busy_before": busy_before,
        "peer_cpu_s": cpu, "peer_runs": calls,
        "cpus": os.cpu_count(), "workers": args.workers,
        "platform": platform.platform(), "python": platform.python_version(),
        "versions": {m: __import__(m).__version__ for m in ("numpy", "pyarrow", "ruptures", "river", "statsmodels", "scipy")},
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(record, indent=2, default=float) + "\n")
    console.print(f"figures written to {args.json} and {args.plot}", highlight=False)
    return 0


if __name__ == "__main__":
    sys.exit(main())
