#!/usr/bin/env python3
"""Benchmark of tightscan's detection (default rule) against numpy, ruptures and plain Parquet reading.

One run, one data set (``tightscan.simulate(N, seed=SEED)``), three comparisons:

(a) ``tightscan.detect_batch`` (default config: elastic window, block torque rates, CUSUM) on
    the in-memory pyarrow table: samples per second, best of ``--repeat`` runs after a warm-up.
(b) The default rule (break scan + CUSUM, ``any``) in vectorised numpy, one Python iteration
    per tightening with numpy inside, on the engine's own tested window, whitening and
    thresholds (what it does and does not reproduce: :func:`default_rule_one`). Its decisions
    are compared with Rust's, tightening by tightening.
(c) The ratio of (a) to (b).
(d) ``tightscan.scan_parquet`` of a Parquet file of the same tightenings against reading that
    file with pyarrow (``pq.read_table``, and iterating ``ParquetFile.iter_batches`` in the
    scan's batches, as the scan reads), for a snappy (pyarrow's default) and an uncompressed file.
(e) ruptures Binseg ``linear`` on a subset: tightenings/s, and Rust's ratio to it.

A sample is one (angle, torque) pair; every rate counts all samples of all tightenings (the
``angle`` list offsets), not only the elastic windows. This is a benchmark, not a test: nothing
fails on time. The figures go to stdout and to ``benches/results/bench_cusum.json``.

Usage: ``.venv/bin/python benches/bench_cusum.py [--n 20000] [--seed 20261121] [--repeat 3] [--parquet-repeat 5]``
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable, NamedTuple

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

import tightscan
from _benchutil import cpu_busy
from tightscan import _core

RESULTS = Path(__file__).resolve().parent / "results" / "bench_cusum.json"

GOAL_RUST_SAMPLES_PER_S = 100e6
GOAL_SPEEDUP_VS_NUMPY = 10.0  # issue 15: against a like-for-like numpy of the default rule
GOAL_SPEEDUP_VS_BINSEG = 100.0
GOAL_SCAN_OVER_READ = 1.25

# Constants of crates/tightscan-core/src/engine/decision.rs.
Z_0999 = 3.090232306
F64_MIN_POSITIVE = sys.float_info.min


# ---------------------------------------------------------------------------------------------
# Timing


class Timing(NamedTuple):
    best: float  # best wall time [s]
    runs: list[float]  # every timed run's wall time [s]
    cores: float  # process CPU time / wall time of the best run (how many cores were busy)
    out: Any  # the last run's result


def best_of(fn: Callable[[], Any], repeat: int, warmup: int = 1) -> Timing:
    """Best wall time (perf_counter) of ``repeat`` calls after ``warmup`` untimed ones."""
    out = None
    for _ in range(warmup):
        out = fn()
    runs, cores = [], []
    for _ in range(repeat):
        c0, t0 = time.process_time(), time.perf_counter()
        out = fn()
        wall = time.perf_counter() - t0
        runs.append(wall)
        cores.append((time.process_time() - c0) / wall)
    i = runs.index(min(runs))
    return Timing(runs[i], runs, cores[i], out)


# ---------------------------------------------------------------------------------------------
# The algorithm in numpy (mirrors crates/tightscan-core/src/{detect,signal,cusum}.rs)


class Params(NamedTuple):
    start_fraction: float
    end_fraction: float
    trim_fraction: float
    min_samples: int
    max_blocks: int
    min_block_samples: int
    training_fraction: float
    min_training_blocks: int
    kappa: float
    h: float


def params_from_defaults() -> Params:
    d = _core.default_config()
    if d["threshold"] is not None:
        h = d["threshold"]
    elif d["arl0"] is not None:
        h = tightscan.cusum_threshold(d["arl0"], d["kappa"], True)
    else:
        # Derived from the CUSUM's share of the decision alpha: read it off the detector.
        curves, _ = tightscan.simulate(20, seed=1)
        h = float(pc.max(tightscan.detect_batch(curves).column("cusum_threshold")).as_py())
    return Params(
        d["zone_start_fraction"], d["zone_end_fraction"], d["zone_trim_fraction"], d["zone_min_samples"],
        d["max_blocks"], d["min_block_samples"], d["training_fraction"], d["min_training_blocks"],
        d["kappa"], h,
    )


class Row(NamedTuple):
    """What the numpy version finds for one tightening (None fields: not analysed / no alarm)."""

    ok: bool
    alarm: bool | None = None
    max_statistic: float | None = None
    reference_rate: float | None = None
    noise_sd: float | None = None
    blocks: int | None = None
    alarm_index: int | None = None
    change_index: int | None = None
    side: str | None = None


FAILED = Row(False)


def _seq_sum(x: np.ndarray) -> float:
    # Left-to-right sum, as Rust's loops add (np.sum adds pairwise, 8 lanes at a time).
    return float(np.cumsum(x)[-1]) if x.size else 0.0


def _first_true(mask: np.ndarray) -> int:
    """Index of the first True, or len(mask) when there is none."""
    k = int(mask.argmax()) if mask.size else 0
    return k if mask.size and mask[k] else mask.size


def cusum_on_window(a: np.ndarray, t: np.ndarray, start: int, end: int, p: Params, h: float) -> Row:
    """The block CUSUM over samples ``[start, end)`` of one tightening, threshold ``h``."""
    length = end - start
    if length < max(p.min_samples, 1) or a[end - 1] <= a[start]:
        return FAILED
    # Equal-angle blocks and their least-squares sums (physics/torque_rate.rs block_stats).
    nb = min(length // p.min_block_samples, p.max_blocks)
    if nb < p.min_training_blocks + 2:
        return FAILED
    wa, wt = a[start:end], t[start:end]
    a0, t0 = float(wa[0]), float(wt[0])
    width = (float(wa[-1]) - a0) / nb
    x = wa - a0
    b = (x * (1.0 / width)).astype(np.int64)  # truncation towards zero, as `as isize`
    np.clip(b, 0, nb - 1, out=b)
    xl = x - b * width
    y = wt - t0
    cnt = np.bincount(b, minlength=nb).astype(np.float64)
    sx = np.bincount(b, xl, nb)
    sy = np.bincount(b, y, nb)
    sxx = np.bincount(b, xl * xl, nb)
    sxy = np.bincount(b, xl * y, nb)
    syy = np.bincount(b, y * y, nb)

    # CSDT stops: runs of unchanged angle 10x the mean run (physics/torque_rate.rs stop_ranges).
    change = np.flatnonzero(wa[1:] != wa[:-1]) + 1
    runs = change.size + 1
    stop_len = max((10 * length) // runs, 10)
    run_start = np.concatenate(([0], change))
    run_end = np.concatenate((change, [length]))
    stops = []
    for r in np.flatnonzero(run_end - run_start >= stop_len):
        i, j = int(run_start[r]), int(run_end[r])
        k = j + _first_true(wt[j:] >= wt[i])
        stops.append((float(wa[i]) - a0, float(wa[min(k, length - 1)]) - a0))

    with np.errstate(divide="ignore", invalid="ignore"):
        sxx_c = sxx - sx * sx / cnt
        usable_mask = (cnt >= 3) & (sxx_c > 1e-9 * width * width)
    if stops:
        blk = np.arange(nb, dtype=np.float64)
        lo_b, hi_b = blk * width, (blk + 1) * width
        for s0, s1 in stops:
            usable_mask &= ~((s0 < hi_b) & (s1 >= lo_b))
    usable = np.flatnonzero(usable_mask)
    n_use = usable.size
    n_train = max(math.ceil(p.training_fraction * n_use), p.min_training_blocks)
    if n_use < n_train + 2:
        return FAILED

    # Per-block slope and residual sum of squares, usable blocks only.
    nu, sxu, syu = cnt[usable], sx[usable], sy[usable]
    sxxu, sxyu, syyu = sxx[usable], sxy[usable], syy[usable]
    sxx_cu = sxx_c[usable]
    sxy_cu = sxyu - sxu * syu / nu
    slope = sxy_cu / sxx_cu
    rss = np.maximum(syyu - syu * syu / nu - sxy_cu * sxy_cu / sxx_cu, 0.0)

    # Reference: pooled slope of the training blocks, in window coordinates.
    tr = slice(0, n_train)
    o = usable[tr] * width
    ntr, sxtr = nu[tr], sxu[tr]
    pn = _seq_sum(ntr)
    psx = _seq_sum(sxtr + ntr * o)
    psy = _seq_sum(syu[tr])
    psxx = _seq_sum(sxxu[tr] + 2.0 * o * sxtr + ntr * o * o)
    psxy = _seq_sum(sxyu[tr] + o * syu[tr])
    reference = (psxy - psx * psy / pn) / (psxx - psx * psx / pn)

    # Noise scale: pooled within-block residual variance, blocks above 20x the median left out.
    dof = np.maximum(nu - 2.0, 1.0)
    var_b = rss / dof
    mid = n_use // 2
    median_var = float(np.partition(var_b, mid)[mid])
    kept = var_b <= 20.0 * median_var
    rss_tot, df = _seq_sum(rss[kept]), _seq_sum(dof[kept])
    rise_to_peak = float(t.max()) - t0
    noise_sd = max(math.sqrt(rss_tot / max(df, 1.0)), 1e-6 * max(abs(rise_to_peak), F64_MIN_POSITIVE))

    # z-scores, dispersion pre-test on the training blocks.
    z = (slope - reference) * np.sqrt(sxx_cu) / noise_sd
    ztr = z[tr]
    sum_z2 = _seq_sum(ztr * ztr)
    kf = float(n_train)
    c = 2.0 / (9.0 * kf)
    q = 1.0 - c + Z_0999 * math.sqrt(c)  # Wilson-Hilferty chi-square(kf) quantile at 0.999
    dispersion = math.sqrt(sum_z2 / kf)
    inflate = dispersion if sum_z2 > kf * (q * q * q) else 1.0
    zm = z[n_train:] / inflate

    # Two-sided CUSUM: S_t = C_t - min(0, min_{s<=t} C_s), C = cumsum(+-z - kappa).
    cp = np.cumsum(zm - p.kappa)
    sp = cp - np.minimum(np.minimum.accumulate(cp), 0.0)
    cn = np.cumsum(-zm - p.kappa)
    sn = cn - np.minimum(np.minimum.accumulate(cn), 0.0)
    max_stat = max(float(sp.max()), float(sn.max()), 0.0)
    up, down = _first_true(sp > h), _first_true(sn > h)
    monitored = zm.size
    if min(up, down) >= monitored:
        return Row(True, False, max_stat, reference, noise_sd * inflate, monitored)
    step, s, side = (up, sp, "increase") if up <= down else (down, sn, "decrease")
    zeros = np.flatnonzero(s[: step + 1] == 0.0)
    change_step = int(zeros[-1]) + 1 if zeros.size else 0
    alarm_blk = int(usable[n_train + step])
    change_blk = int(usable[n_train + change_step])
    alarm_index = start + int(np.flatnonzero(b == alarm_blk)[-1])
    change_index = start + int(np.flatnonzero(b == change_blk)[0])
    return Row(True, True, max_stat, reference, noise_sd * inflate, monitored, alarm_index, change_index, side)


# ---------------------------------------------------------------------------------------------
# The default rule (break + CUSUM, "any") in numpy, on the engine's own window


class RuleRow(NamedTuple):
    """What the numpy default rule decides for one tightening (``ok`` False: not analysed)."""

    ok: bool
    change: bool = False
    break_fired: bool = False
    break_statistic: float | None = None
    break_split: int | None = None
    cusum: Row = FAILED


def sup_lr(x: np.ndarray, y: np.ndarray, phi: float = 0.0) -> tuple[float, int] | None:
    """sup-LR of one break in ``y = a + b x`` under AR(1) noise of coefficient ``phi``, the GLS
    form (detectors/gls_breakpoint.rs ``gls_sup_lr_scan``): ``x``, ``y`` recorded, whitened
    here; columns 1, the whitened angle, the whitened step (1 at the split, ``1 - phi`` after
    it) and the whitened step x angle (the recorded angle at the split, the whitened one
    after it), over every split with ``max(ceil(5 % n), 10)`` whitened samples a side, the
    normal equations from prefix sums. The statistic and the split (a whitened sample)."""
    gain = 1.0 - phi
    # White noise (phi 0) keeps every sample, as the engine does with no noise model.
    wy, wx, x_at = (y[1:] - phi * y[:-1], x[1:] - phi * x[:-1], x[1:]) if phi else (y, x, x)
    n = wx.size
    m = max(math.ceil(0.05 * n), 10)
    if n < 2 * m:
        return None

    def pre(v: np.ndarray) -> np.ndarray:
        return np.concatenate(([0.0], np.cumsum(v)))

    p1, p2, pt, pt2, pq = pre(wx), pre(wx * wx), pre(wy), pre(wy * wy), pre(wx * wy)
    sxx = p2[n] - p1[n] ** 2 / n
    rss0 = (pt2[n] - pt[n] ** 2 / n) - (pq[n] - p1[n] * pt[n] / n) ** 2 / sxx
    ks = np.arange(m, n - m + 1)
    after = ks + 1
    cnt = (n - after).astype(np.float64)
    r1, r2, rt, rq = p1[n] - p1[after], p2[n] - p2[after], pt[n] - pt[after], pq[n] - pq[after]
    xk, wk, yk = x_at[ks], wx[ks], wy[ks]
    gram = np.empty((ks.size, 4, 4))
    gram[:, 0, 0], gram[:, 0, 1], gram[:, 1, 1] = n, p1[n], p2[n]
    gram[:, 0, 2], gram[:, 0, 3] = gain * cnt + 1.0, r1 + xk
    gram[:, 1, 2], gram[:, 1, 3] = gain * r1 + wk, r2 + wk * xk
    gram[:, 2, 2], gram[:, 2, 3], gram[:, 3, 3] = gain * gain * cnt + 1.0, gain * r1 + xk, r2 + xk * xk
    for i in range(4):
        for j in range(i):
            gram[:, i, j] = gram[:, j, i]
    rhs = np.stack([np.full(ks.size, pt[n]), np.full(ks.size, pq[n]), gain * rt + yk, rq + xk * yk], axis=1)
    # A split whose normal equations are singular (the recorded angle standing still over the
    # step's side, as in a CSDT pause) explains nothing beyond the line, as in the engine (its
    # 2 x 2 step block must be invertible there, else the split's RSS is the line's). numpy's
    # batched solve raises for the whole stack on one singular matrix, so those are set aside.
    singular = ~(np.abs(np.linalg.det(gram)) > 0.0)
    gram[singular] = np.eye(4)
    with np.errstate(divide="ignore", invalid="ignore"):
        theta = np.linalg.solve(gram, rhs[..., None])[..., 0]
        rss = pt2[n] - np.sum(theta * rhs, axis=1)
        lr = n * np.log(rss0 / np.maximum(rss, 1e-300 * rss0))
    lr = np.where(singular, 0.0, np.where(np.isfinite(lr), lr, -np.inf))
    j = int(np.argmax(lr))
    return float(lr[j]), int(ks[j])


def default_rule_one(a: np.ndarray, t: np.ndarray, window: tuple[float, float], lag1: float, break_cv: float, h: float, p: Params) -> RuleRow:
    """One tightening under the default rule: a change when the break scan or the CUSUM fires.

    Taken from the engine's result row (not recomputed): the tested window
    (``tested_start_angle`` .. ``tested_end_angle``), the AR(1) whitening coefficient
    (``noise_lag1``), the break scan's critical value (``break_critical_value``, from the
    shipped null table at its share of alpha) and the CUSUM threshold (``cusum_threshold``).
    Reproduced: the sup-LR scan on the whitened window and its decision, the block CUSUM (as
    above) on the window, the ``any`` rule. Not reproduced: the elastic window's and the
    noise model's estimation (taken as given, which flatters numpy's time), the stop samples
    left out inside the window, the weights of noise growing with the torque, AR models of
    order > 1 and the whitening's own uncertainty, the end-of-curve (Chow) test of the break
    detector, its encoder-step rule on the smoothed angle (applied here on the recorded one), and
    the statuses that demote an alarm (``model_misfit``).
    """
    idx = np.flatnonzero((a >= window[0]) & (a <= window[1]))
    if idx.size < 20:
        return RuleRow(False)
    start, end = int(idx[0]), int(idx[-1]) + 1
    x, y = a[start:end] - a[start], t[start:end] - t[start]
    scan = sup_lr(x, y, lag1 or 0.0)
    if lag1:
        x, y = x[1:] - lag1 * x[:-1], y[1:] - lag1 * y[:-1]
    fired = bool(scan is not None and scan[0] > break_cv)
    if fired and scan is not None and scan[0] <= 2.0 * break_cv:
        # the encoder-step rule: a break counts when its jump exceeds 1.5 encoder steps
        # (physics/torque_rate.rs encoder_resolution; engine/analysis/breaks.rs)
        wa, wt = a[start:end], t[start:end]
        steps = np.diff(wa)
        positive = steps[steps > 1e-9]
        resolution = 0.0
        if positive.size:
            smallest = float(positive.min())
            q = steps / smallest
            if np.count_nonzero(np.abs(q - np.round(q)) < 0.05) * 10 >= 9 * steps.size:
                resolution = smallest
        dx, dy = float(wa[-1] - wa[0]), float(wt[-1] - wt[0])
        encoder_step = abs(dy / dx) * resolution if dx > 0 else 0.0
        if encoder_step > 0:
            k = scan[1] + (1 if lag1 else 0)
            bl, al = np.polyfit(wa[:k], wt[:k], 1)
            br, ar = np.polyfit(wa[k:], wt[k:], 1)
            jump = (ar + br * wa[k]) - (al + bl * wa[k])
            fired = bool(abs(jump) > 1.5 * encoder_step)
    cusum = cusum_on_window(a, t, start, end, p, h) if idx.size >= 50 else FAILED
    change = fired or bool(cusum.ok and cusum.alarm)
    return RuleRow(True, change, fired, scan[0] if scan else None, start + scan[1] + (1 if lag1 else 0) if scan else None, cusum)


class EngineInputs(NamedTuple):
    """What the numpy reference takes from the engine's results (see :func:`default_rule_one`)."""

    lo: np.ndarray
    hi: np.ndarray
    lag1: np.ndarray
    break_cv: np.ndarray
    h: np.ndarray


def engine_inputs(rust: pa.Table) -> EngineInputs:
    def col(name: str) -> np.ndarray:
        return np.asarray(rust.column(name).to_numpy(zero_copy_only=False), dtype=np.float64)

    return EngineInputs(col("tested_start_angle"), col("tested_end_angle"), np.nan_to_num(col("noise_lag1")), col("break_critical_value"), col("cusum_threshold"))


def default_rule_numpy(table: pa.Table, eng: EngineInputs, p: Params) -> list[RuleRow]:
    """Python loop over tightenings, numpy inside (float32 -> float64 conversion included)."""
    angle = table.column("angle").combine_chunks()
    torque = table.column("torque").combine_chunks()
    offsets = angle.offsets.to_numpy()
    a_all = angle.values.to_numpy(zero_copy_only=False).astype(np.float64)
    t_all = torque.values.to_numpy(zero_copy_only=False).astype(np.float64)
    rows = []
    for i in range(len(offsets) - 1):
        if not (np.isfinite(eng.lo[i]) and np.isfinite(eng.hi[i])):
            rows.append(RuleRow(False))
            continue
        s, e = offsets[i], offsets[i + 1]
        h = eng.h[i] if np.isfinite(eng.h[i]) else p.h
        cv = eng.break_cv[i] if np.isfinite(eng.break_cv[i]) else math.inf
        rows.append(default_rule_one(a_all[s:e], t_all[s:e], (eng.lo[i], eng.hi[i]), eng.lag1[i], cv, h, p))
    return rows


def compare_rule(rust: pa.Table, rows: list[RuleRow]) -> dict[str, Any]:
    """Fraction of identical decisions (``change_detected``, the break detector's alarm) and
    how close the break statistic and split are, over the tightenings both analysed."""
    detected = rust.column("change_detected").to_pylist()
    brk = rust.column("break_alarm").to_pylist()
    stat = rust.column("break_statistic").to_pylist()
    split = rust.column("break_change_index").to_pylist()
    both = same_change = same_break = same_split = rust_changes = numpy_changes = 0
    rel = []
    for i, r in enumerate(rows):
        if detected[i] is None or not r.ok:
            continue
        both += 1
        same_change += bool(detected[i]) == r.change
        same_break += bool(brk[i]) == r.break_fired
        rust_changes += bool(detected[i])
        numpy_changes += r.change
        if stat[i] is not None and r.break_statistic is not None:
            rel.append(abs(stat[i] - r.break_statistic) / max(abs(stat[i]), 1e-12))
            same_split += split[i] == r.break_split
    return {
        "tightenings": len(rows),
        "decided_by_both": both,
        "change_detected_agreement": same_change / both if both else None,
        "break_alarm_agreement": same_break / both if both else None,
        "rust_changes": rust_changes,
        "numpy_changes": numpy_changes,
        "break_statistic_within_1pct": float(np.mean(np.array(rel) <= 0.01)) if rel else None,
        "break_split_equal": same_split / len(rel) if rel else None,
    }


def ruptures_binseg_rate(table: pa.Table, rust: pa.Table, n: int) -> dict[str, Any]:
    """ruptures Binseg, ``model="linear"`` (a line per segment), one break, on the engine's
    tested window of the first ``n`` tightenings: tightenings/s (the fastest Python peer that
    reaches our recall, benches/detection_quality.py)."""
    import warnings

    import ruptures as rpt

    eng = engine_inputs(rust)
    angle = table.column("angle").combine_chunks()
    torque = table.column("torque").combine_chunks()
    offsets = angle.offsets.to_numpy()
    a_all = angle.values.to_numpy(zero_copy_only=False).astype(np.float64)
    t_all = torque.values.to_numpy(zero_copy_only=False).astype(np.float64)
    windows = []
    for i in range(min(n, len(offsets) - 1)):
        a, t = a_all[offsets[i] : offsets[i + 1]], t_all[offsets[i] : offsets[i + 1]]
        keep = (a >= eng.lo[i]) & (a <= eng.hi[i])
        if keep.sum() >= 20:
            x = a[keep]
            windows.append((t[keep], np.column_stack([x, np.ones_like(x)])))

    def run() -> None:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for y, design in windows:
                rpt.Binseg(model="linear", min_size=10, jump=1).fit(np.column_stack([y, design])).predict(n_bkps=1)

    t0 = time.perf_counter()
    run()
    wall = time.perf_counter() - t0
    return {"tightenings": len(windows), "seconds": wall, "tightenings_per_s": len(windows) / wall}


# ---------------------------------------------------------------------------------------------
# Comparison of the numpy rows with the Rust results


# ---------------------------------------------------------------------------------------------
# Parquet: scan versus read


def parquet_figures(table: pa.Table, samples: int, repeat: int, tmp: Path) -> dict[str, Any]:
    out: dict[str, Any] = {}
    from tightscan._scan import BATCH_BYTES

    for compression in ("snappy", "none"):
        src = tmp / f"tightenings-{compression}.parquet"
        dst = tmp / f"results-{compression}.parquet"
        pq.write_table(table, src, compression=compression)
        meta = pq.read_metadata(src)
        widest = max(meta.row_group(i).total_byte_size / meta.row_group(i).num_rows for i in range(meta.num_row_groups))
        batch_size = max(1, int(BATCH_BYTES // widest))  # scan_parquet's default batches

        def read_table() -> int:
            return int(pq.read_table(src).num_rows)

        def read_batches() -> int:
            reader = pq.ParquetFile(src, buffer_size=1 << 20, pre_buffer=False)
            return sum(b.num_rows for b in reader.iter_batches(batch_size=batch_size))

        def scan() -> int:
            return tightscan.scan_parquet(src, dst, progress=False).tightenings

        t_read_table = best_of(read_table, repeat).best
        t_read_batches = best_of(read_batches, repeat).best
        t_scan, scan_times, scan_cores, rows = best_of(scan, repeat)
        if rows != table.num_rows:
            raise RuntimeError(f"scan_parquet reported {rows} rows, expected {table.num_rows}")

        # Breakdown: detection alone on the batches the scan reads, and writing the results.
        batches = list(pq.ParquetFile(src).iter_batches(batch_size=batch_size))
        t_detect_batches, _, _, results = best_of(lambda: [_core.detect(b, None, [], 0) for b in batches], repeat)
        res_table = pa.Table.from_batches([rb for r in results for rb in r.to_batches()])

        def write() -> None:
            pq.write_table(res_table, tmp / "write-only.parquet")

        t_write = best_of(write, repeat).best
        t_read = min(t_read_table, t_read_batches)
        out[compression] = {
            "file_bytes": src.stat().st_size,
            "read_table_s": t_read_table,
            "read_batches_s": t_read_batches,
            "scan_parquet_s": t_scan,
            "scan_parquet_runs_s": scan_times,
            "scan_parquet_cores_busy": scan_cores,
            "scan_over_read_table": t_scan / t_read_table,
            "scan_over_read_batches": t_scan / t_read_batches,
            "scan_over_fastest_read": t_scan / t_read,
            "scan_samples_per_s": samples / t_scan,
            "breakdown_detect_on_read_batches_s": t_detect_batches,
            "breakdown_write_results_s": t_write,
            "breakdown_unexplained_s": t_scan - t_read_batches - t_detect_batches - t_write,
        }
    return out


# ---------------------------------------------------------------------------------------------


def single_thread_worker(n: int, seed: int, repeat: int) -> None:
    """Child process (RAYON_NUM_THREADS=1): times detect_batch on the same data, prints JSON."""
    table, _ = tightscan.simulate(n, seed=seed)
    table = table.combine_chunks()
    timing = best_of(lambda: tightscan.detect_batch(table), repeat)
    print(json.dumps({"best": timing.best, "runs": timing.runs, "cores": timing.cores}))


def time_single_thread(n: int, seed: int, repeat: int) -> dict[str, Any] | None:
    """detect_batch on one rayon thread, in a child process (the pool is fixed at first use)."""
    cmd = [sys.executable, os.path.abspath(__file__), "--n", str(n), "--seed", str(seed),
           "--repeat", str(repeat), "--single-thread-worker"]
    proc = subprocess.run(cmd, env={**os.environ, "RAYON_NUM_THREADS": "1"}, capture_output=True, text=True)
    if proc.returncode != 0:
        print(f"warning: single-thread run failed: {proc.stderr.strip()[-500:]}", file=sys.stderr)
        return None
    result: dict[str, Any] = json.loads(proc.stdout.strip().splitlines()[-1])
    return result


def fmt_rate(x: float) -> str:
    return f"{x / 1e6:8.1f} M samples/s"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=20_000, help="tightenings to simulate (default 20000)")
    ap.add_argument("--seed", type=int, default=20261121, help="simulation seed")
    ap.add_argument("--repeat", type=int, default=3, help="timed runs per figure; the best counts (default 3)")
    ap.add_argument("--parquet-repeat", type=int, default=5,
                    help="timed runs per Parquet figure (default 5: file reads vary more, with page faults)")
    ap.add_argument("--peer-n", type=int, default=300, help="tightenings handed to ruptures Binseg (default 300)")
    ap.add_argument("--json", type=Path, default=RESULTS, help=f"where to write the figures (default {RESULTS})")
    ap.add_argument("--single-thread-worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.single_thread_worker:
        single_thread_worker(args.n, args.seed, args.repeat)
        return 0
    if _core.DEBUG_BUILD:
        print("warning: tightscan._core is a debug build; run `make build` for release figures", file=sys.stderr)

    busy_before = cpu_busy()
    if busy_before is not None and busy_before > 0.10:
        print(f"warning: {busy_before:.0%} of the CPUs were busy before the run: other processes compete "
              f"and the figures will be low", file=sys.stderr)
    print(f"simulating {args.n} tightenings (seed {args.seed}) ...", flush=True)
    t0 = time.perf_counter()
    table, _truth = tightscan.simulate(args.n, seed=args.seed)
    t_sim = time.perf_counter() - t0
    table = table.combine_chunks()
    offsets = table.column("angle").chunk(0).offsets
    samples = int(offsets[-1].as_py() - offsets[0].as_py())
    print(f"  {samples:,} samples ({samples / args.n:.0f} per tightening) in {t_sim:.2f} s", flush=True)

    # (a) Rust
    print("timing detect_batch ...", flush=True)
    t_rust, rust_runs, rust_cores, rust = best_of(lambda: tightscan.detect_batch(table), args.repeat)
    rust_rate = samples / t_rust
    single = time_single_thread(args.n, args.seed, args.repeat)

    # (b) numpy, the default rule on the engine's window (warm-up on a slice: the full run takes seconds)
    print("timing the numpy version of the default rule ...", flush=True)
    p = params_from_defaults()
    eng = engine_inputs(rust)
    default_rule_numpy(table.slice(0, min(args.n, 200)), eng, p)
    t_np, np_runs, np_cores, rows = best_of(lambda: default_rule_numpy(table, eng, p), args.repeat, warmup=0)
    np_rate = samples / t_np
    agreement = compare_rule(rust, rows)

    # (e) ruptures Binseg linear, the fastest Python peer at our recall, on a subset
    print("timing ruptures Binseg (linear) ...", flush=True)
    peer_n = min(args.n, args.peer_n)
    try:
        binseg: dict[str, Any] | None = ruptures_binseg_rate(table, rust, peer_n)
    except ImportError:
        binseg = None
    rust_tightenings_per_s = args.n / t_rust
    binseg_ratio = rust_tightenings_per_s / binseg["tightenings_per_s"] if binseg else None

    # (d) Parquet
    print("timing scan_parquet and pyarrow reads ...", flush=True)
    with tempfile.TemporaryDirectory(prefix="tightscan-bench-") as tmp:
        parquet = parquet_figures(table, samples, args.parquet_repeat, Path(tmp))

    speedup = t_np / t_rust
    snappy = parquet["snappy"]
    status_codes: dict[str, int] = {}
    for item in pc.value_counts(rust.column("status")).to_pylist():
        code = item["values"].split(":")[0]
        status_codes[code] = status_codes.get(code, 0) + item["counts"]

    line = "-" * 78
    print()
    print(line)
    print(f"tightscan CUSUM benchmark  N = {args.n:,} tightenings, {samples:,} samples, "
          f"{os.cpu_count()} CPUs, best of {args.repeat} ({args.parquet_repeat} for Parquet)")
    if busy_before is not None:
        print(f"CPUs busy with other work just before the run: {busy_before:.0%}")
    print(line)
    print(f"(a) Rust detect_batch          {t_rust * 1e3:9.1f} ms  {fmt_rate(rust_rate)}  ({rust_cores:.2f} cores busy)")
    if single is not None:
        print(f"    same, on 1 rayon thread    {single['best'] * 1e3:9.1f} ms  {fmt_rate(samples / single['best'])}"
              f"  (RAYON_NUM_THREADS=1)")
    print(f"(b) numpy, loop per tightening {t_np * 1e3:9.1f} ms  {fmt_rate(np_rate)}  ({np_cores:.2f} cores busy)")
    print(f"(c) Rust / numpy speed-up      {speedup:9.1f} x" + (
        f"   (per core, Rust on 1 thread: {t_np / single['best']:.1f} x)" if single is not None else ""))
    print(f"    statuses (Rust): {status_codes}")
    print(f"    numpy vs Rust (default rule): change_detected identical on {agreement['change_detected_agreement']:.2%} "
          f"of {agreement['decided_by_both']:,} tightenings ({agreement['rust_changes']} Rust changes, {agreement['numpy_changes']} numpy);"
          f" break alarm identical on {agreement['break_alarm_agreement']:.2%}, break statistic within 1 % on "
          f"{agreement['break_statistic_within_1pct']:.2%}, same split on {agreement['break_split_equal']:.2%}")
    if binseg is not None and binseg_ratio is not None:
        print(f"(e) ruptures Binseg linear      {binseg['tightenings_per_s']:9.1f} tightenings/s on {binseg['tightenings']} windows;"
              f" Rust {rust_tightenings_per_s:,.0f}/s: {binseg_ratio:.0f} x")
    print("(d) Parquet                     snappy        none")
    for key, label in [
        ("file_bytes", "file size [MB]"),
        ("read_table_s", "pq.read_table [ms]"),
        ("read_batches_s", "iter_batches [ms]"),
        ("scan_parquet_s", "scan_parquet [ms]"),
        ("scan_over_read_table", "scan / read_table"),
        ("scan_over_read_batches", "scan / iter_batches"),
        ("breakdown_detect_on_read_batches_s", "  of which detect [ms]"),
        ("breakdown_write_results_s", "  of which write [ms]"),
        ("breakdown_unexplained_s", "  of which other [ms]"),
    ]:
        vals = [parquet[c][key] for c in ("snappy", "none")]
        if key == "file_bytes":
            cells = [f"{v / 1e6:11.1f}" for v in vals]
        elif key.endswith("_s"):
            cells = [f"{v * 1e3:11.1f}" for v in vals]
        else:
            cells = [f"{v:11.2f}" for v in vals]
        print(f"    {label:<27}{cells[0]} {cells[1]}")
    print(line)
    worst_scan = max(parquet[c]["scan_over_fastest_read"] for c in ("snappy", "none"))
    goals = {
        "rust_samples_per_s": (rust_rate >= GOAL_RUST_SAMPLES_PER_S, f">= {GOAL_RUST_SAMPLES_PER_S / 1e6:.0f} M samples/s", f"{rust_rate / 1e6:.1f} M"),
        "speedup_vs_numpy": (speedup >= GOAL_SPEEDUP_VS_NUMPY, f">= {GOAL_SPEEDUP_VS_NUMPY:.0f}x numpy (default rule)", f"{speedup:.1f}x"),
        "speedup_vs_binseg": (binseg_ratio is not None and binseg_ratio >= GOAL_SPEEDUP_VS_BINSEG, f">= {GOAL_SPEEDUP_VS_BINSEG:.0f}x ruptures Binseg linear", f"{binseg_ratio:.0f}x" if binseg_ratio else "not run"),
        "scan_over_read": (worst_scan <= GOAL_SCAN_OVER_READ, f"scan <= {GOAL_SCAN_OVER_READ}x fastest read (worst file)", f"{worst_scan:.2f}x"),
    }
    print("goals:")
    for name, (met, goal, value) in goals.items():
        print(f"    {'met   ' if met else 'MISSED'}  {goal:<45} {value}")
    print(line)

    record = {
        "timestamp": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "n_tightenings": args.n,
        "seed": args.seed,
        "samples": samples,
        "repeat": args.repeat,
        "parquet_repeat": args.parquet_repeat,
        "cpus": os.cpu_count(),
        "cpu_busy_before": busy_before,
        "platform": platform.platform(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "pyarrow": pa.__version__,
        "tightscan": getattr(_core, "__version__", None),
        "simulate_s": t_sim,
        "rust_detect_batch_s": t_rust,
        "rust_detect_batch_runs_s": rust_runs,
        "rust_samples_per_s": rust_rate,
        "rust_cores_busy": rust_cores,
        "numpy_s": t_np,
        "numpy_runs_s": np_runs,
        "numpy_samples_per_s": np_rate,
        "numpy_cores_busy": np_cores,
        "speedup_rust_over_numpy": speedup,
        "rust_1_thread_detect_batch_s": single["best"] if single else None,
        "rust_1_thread_samples_per_s": samples / single["best"] if single else None,
        "speedup_rust_1_thread_over_numpy": t_np / single["best"] if single else None,
        "rust_status_counts": status_codes,
        "agreement": agreement,
        "numpy_reference": "default rule (break + CUSUM, any) on the engine's tested window; see default_rule_one",
        "ruptures_binseg": binseg,
        "speedup_rust_over_binseg": binseg_ratio,
        "rust_tightenings_per_s": rust_tightenings_per_s,
        "parquet": parquet,
        "goals": {k: {"met": v[0], "goal": v[1], "value": v[2]} for k, v in goals.items()},
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(record, indent=2) + "\n")
    print(f"figures written to {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
