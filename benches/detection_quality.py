#!/usr/bin/env python3
"""Detection-quality benchmark: how well tightscan's detectors find friction changes, next to
off-the-shelf change-point methods given more help than ours get, on BOTH generators and a
grid of noise colours and channels, in one run (issue 11, items 2 and 5).

This is a benchmark, not a test: nothing fails. Every figure printed is measured in the run
that prints it, on curves generated in that run (seeded).

Generators: the built-in simulator (``tightscan.simulate``, its own noise switched off and the
cell's noise added here) and the independent generator of the tests
(``tests/independent_generator``: plain numpy, written from the physics texts without the
simulator's code). Both draw all strategies (CST/CSDT/HDT), all fault kinds
(abrupt/incipient/intermittent), friction changes of either sign with |relative change of mu|
uniform in 3-45 %, on either friction coefficient or both; no clamp-force channel.

Cells (``CELLS``): noise white, AR(1) phi 0.5 and 0.85 (same marginal sd), Student t4 (same
sd) at a constant level per curve (built-in: 0.2 % of the target torque, its calibration level;
independent: 0.01 Nm + 0.4 % of the target, the setting of the issue), and noise proportional
to the torque (0.01 Nm + 0.4 % of |torque|), at 2 kHz with a 0.1 deg encoder; plus white noise
off that channel grid: 1 kHz with a 0.2 deg encoder and 10 kHz with 0.1 deg.

In every generator x cell, three sets of ``--n`` curves with distinct seeds:

- ``calibration`` (clean): only used to set thresholds at a 1 % false-alarm rate per curve;
- ``clean`` (another seed): the false-alarm rates reported (out of sample);
- ``faulty`` (every curve carries a fault): recall, onset error. A faulty curve whose onset the
  bolt never reached (the tool stopped first: the curve holds no change) is left out of recall
  (counted in ``faulty_onset_not_reached``).

Ours: every detector found in the result columns (``X_alarm`` with ``X_change_angle`` or
``X_alarm_angle``; opt-in detectors switched on) at its configured rate and at a matched 1 %
rate on a continuous statistic calibrated on the cell's calibration set; and the default
decision rule ``change_detected`` / ``change_angle`` at its configured alpha (0.01) as a user
runs it (not recalibrated: its false-alarm rate is what it is). Ours see the whole curve and
find the window themselves; a tightening whose ``status`` is not ``ok`` counts as a miss.

Peers (ruptures Binseg/Pelt with ``linear`` and ``l2``-on-the-rate costs, statsmodels OLS-CUSUM,
river PageHinkley/ADWIN) see only the TRUE elastic window from the truth table and are
calibrated to 1 % on the cell's calibration curves. They run on the first ``--peer-n`` curves of
each set (pure Python); ours are also scored on exactly those curves (like-for-like rows).

Recall is reported against |magnitude| (bands 3-6, 6-10, 10-15, 15-30, 30-45 %), against the
onset position in the true window (thirds), per strategy and per fault kind; onset errors are
medians over detected abrupt changes. The goals of issue 11 item 2 (recall >= 0.995 on
15-45 %, >= 0.92 on 3-15 %, median abrupt onset error <= 0.2 deg, FA <= 1 %) are checked for
the decision rule in every generator x cell, PASS or MISS on the point estimate, with the best
peer's figures beside.

Written: stdout tables; ``benches/results/detection_quality.json`` (top-level keys as before for
the reference cell, built-in white; every cell under ``cells``; recall curves under
``recall_vs_magnitude``: ``edges`` and ``same_curves``/``ours_all_curves`` for the reference
cell on 3 %-wide bins, and ``by_cell`` on the bands: a list of rows {generator, cell,
strategy ("all" or CST/CSDT/HDT), detector, point, family, recall: [..], n: [..]});
``benches/results/detection_quality.md`` (the table the READMEs include: ``--write-readme``
rewrites the block between ``<!-- detection_quality:begin -->`` and ``<!-- detection_quality:end
-->`` in README.md and benches/README.md); ``benches/results/recall_vs_magnitude.png``.

Usage: ``.venv/bin/python benches/detection_quality.py [--quick] [--n N] [--peer-n M]
[--cells white,t4,...] [--generators built-in,independent] [--seed S] [--write-readme]``
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
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import pandas as pd
import pyarrow as pa
from scipy.signal import lfilter

import tightscan
from _benchutil import cpu_busy
from tightscan import _core
from peers import ADWIN_LOG10_RANGE, calibrate_pelt, check_linear_cost, FA_TARGET, peer_statistics, peer_streaming, peer_windows, PeerCurve, PeerSettings, pelt_fires, pool_map, STOP_RPM
from scoring import (BANDS, deg, FAULT_KINDS, GOAL_FA, GOAL_ONSET_ABRUPT_DEG, GOAL_RECALL_LARGE, GOAL_RECALL_SMALL, ONSET_THIRDS,
                     Outcome, pct, plot, print_tables, recall_curve, score)

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
import independent_generator as ig  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
JSON_PATH = RESULTS / "detection_quality.json"
MD_PATH = RESULTS / "detection_quality.md"
PLOT_PATH = RESULTS / "recall_vs_magnitude.png"
README_BLOCKS = (ROOT / "README.md", ROOT / "benches" / "README.md")
BEGIN, END = "<!-- detection_quality:begin -->", "<!-- detection_quality:end -->"

STRATEGIES = ("CST", "CSDT", "HDT")
MAGNITUDE_RANGE = (0.03, 0.45)
GENERATORS = ("built-in", "independent")

# A detector whose angles are only reported when it alarms must be rerun at the matched
# threshold to give angles there: prefix -> the config key that sets its threshold in the units
# of its statistic (CUSUM h and the 3-sigma baseline's k, both in sigma).
MATCHED_RERUN_KEYS = {"cusum": "threshold", "shewhart": "shewhart_k"}
PEER_NAMES = ["binseg_linear", "pelt_linear", "binseg_l2_rate", "pelt_l2_rate", "pagehinkley", "adwin", "ols_cusum"]
BEST_PEER = "binseg_linear"  # the peer the issue compares with (ruptures Binseg, linear cost, true window)


@dataclass(frozen=True)
class Cell:
    """One noise / channel setting, applied to both generators."""

    name: str
    colour: str = "white"  # white, ar1, t4
    phi: float = 0.0
    proportional: bool = False  # sd grows with the torque instead of a constant per curve
    rate_hz: float = 2000.0
    encoder_deg: float = 0.1


CELLS = (
    Cell("white"), Cell("ar1 0.5", "ar1", 0.5), Cell("ar1 0.85", "ar1", 0.85), Cell("t4", "t4"),
    Cell("proportional", proportional=True), Cell("1 kHz 0.2 deg", rate_hz=1000.0, encoder_deg=0.2),
    Cell("10 kHz 0.1 deg", rate_hz=10000.0, encoder_deg=0.1),
)
QUICK_CELLS = ("white", "ar1 0.85")
REFERENCE = ("built-in", "white")  # the cell whose figures fill the top-level keys of the JSON


# ---------------------------------------------------------------------------------------------
# Generation


def unit_noise(rng: np.random.Generator, n: int, colour: str, phi: float) -> np.ndarray:
    """Unit-variance noise of the colour asked for (the same marginal sd whatever phi)."""
    if colour == "t4":
        return np.asarray(rng.standard_t(4, size=n) / math.sqrt(2.0))  # t4 has variance 2
    e = rng.normal(size=n)
    if colour == "ar1" and phi > 0:
        # Stationary start: e[0] = phi x0 + sqrt(1 - phi^2) z0 with x0 ~ N(0, 1).
        e = lfilter([math.sqrt(1.0 - phi * phi)], [1.0, -phi], e, zi=[phi * rng.normal()])[0]
    return np.asarray(e)


def _with_noise(curves: pa.Table, cell: Cell, seed: int) -> pa.Table:
    """The built-in simulator's noise-free torque plus the cell's noise."""
    rng = np.random.default_rng([seed, 7])
    torque = curves.column("torque").combine_chunks()
    offsets = torque.offsets.to_numpy()
    values = torque.values.to_numpy(zero_copy_only=False).astype(np.float64)
    targets = curves.column("target_torque").to_numpy()
    noisy = np.empty_like(values)
    for i in range(len(offsets) - 1):
        s, e = offsets[i], offsets[i + 1]
        t = values[s:e]
        sd = 0.01 + 0.004 * np.abs(t) if cell.proportional else 0.002 * targets[i]
        noisy[s:e] = t + sd * unit_noise(rng, e - s, cell.colour, cell.phi)
    arr = pa.ListArray.from_arrays(pa.array(offsets.astype(np.int32)), pa.array(noisy))
    return curves.set_column(curves.column_names.index("torque"), "torque", arr.cast(curves.schema.field("torque").type))


def generate(generator: str, cell: Cell, n: int, seed: int, faulty: bool) -> tuple[pa.Table, pd.DataFrame]:
    """``n`` curves of one generator and cell, and their truth in common columns:
    ``true_strategy``, ``true_fault_kind``, ``true_magnitude`` (signed), ``true_onset_angle``,
    ``true_window_start``/``true_window_end`` (the true elastic window), ``true_onset_reached``,
    ``true_onset_position`` (onset as a fraction of the window)."""
    if generator == "built-in":
        curves, truth = tightscan.simulate(
            n, seed=seed, fault_fraction=1.0 if faulty else 0.0, strategies=list(STRATEGIES), fault_kinds=list(FAULT_KINDS),
            magnitude_range=MAGNITUDE_RANGE, torque_noise=0.0, sample_rate_hz=cell.rate_hz, angle_resolution_deg=cell.encoder_deg)
        curves = _with_noise(curves, cell, seed)
        t = truth.to_pandas()
        ws, we = t["elastic_start_angle"].to_numpy(float), t["final_angle"].to_numpy(float)
        onset = t["onset_angle"].to_numpy(float, na_value=np.nan)
        reached = np.isfinite(onset) & (onset <= we)
    else:
        constant = dict(sd_nm=0.01, sd_rel=0.0, sd_target_rel=0.004)
        level = dict(sd_nm=0.01, sd_rel=0.004, sd_target_rel=0.0) if cell.proportional else constant
        noise = ig.NoiseConfig(colour=cell.colour, phi=cell.phi, **level)  # type: ignore[arg-type]
        fault = (ig.FaultConfig(kind="mix", magnitude=MAGNITUDE_RANGE, signed=True, acts_on="mix") if faulty
                 else ig.FaultConfig(kind=None))
        curves, truth = ig.generate(ig.GeneratorConfig(n=n, seed=seed, strategy="mix", sample_rate_hz=cell.rate_hz,
                                                       encoder_step_deg=cell.encoder_deg, noise=noise, fault=fault))
        t = truth.to_pandas()
        ws, we = t["window_start_angle"].to_numpy(float), t["window_end_angle"].to_numpy(float)
        onset = t["onset_angle"].to_numpy(float, na_value=np.nan)
        reached = t["onset_reached"].fillna(False).to_numpy(bool) & np.isfinite(onset)
    frame = pd.DataFrame({
        "true_strategy": t["strategy"].to_numpy(), "true_fault_kind": t["fault_kind"].to_numpy() if faulty else None,
        "true_magnitude": t["magnitude"].to_numpy(float, na_value=np.nan) if faulty else np.nan,
        "true_onset_angle": onset, "true_window_start": ws, "true_window_end": we, "true_onset_reached": reached,
        "true_onset_position": (onset - ws) / np.maximum(we - ws, 1e-9), "true_n_samples": t["n_samples"].to_numpy(),
    })
    return curves, frame


# ---------------------------------------------------------------------------------------------
# Our detectors and thresholds


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
    order of preference: ``X_p_value`` (comparable between curves of different lengths), then
    ``X_statistic``, ``X_max_statistic`` and any other ``X_max_*``."""
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
    """The first candidate statistic fine enough to set a 1 % rate on the calibration curves
    (a clipped p-value tying at the threshold so that fewer than half the target exceed it gives
    way to the next)."""
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


def detect(curves: pa.Table, truth: pd.DataFrame, config: dict[str, Any], reruns: dict[str, dict[str, Any]]) -> pd.DataFrame:
    """``detect_batch`` with ``config``, and once more per rerun (keeping that prefix's columns as
    ``matched_<col>``), beside the truth."""
    res = tightscan.detect_batch(curves, config)
    assert isinstance(res, pa.Table)
    rf = res.to_pandas()
    for p, cfg in reruns.items():
        rr = tightscan.detect_batch(curves, cfg)
        assert isinstance(rr, pa.Table)
        sub = rr.select([c for c in rr.column_names if c.startswith(f"{p}_")]).to_pandas()
        rf = pd.concat([rf, sub.add_prefix("matched_")], axis=1)
    return pd.concat([truth.reset_index(drop=True), rf], axis=1)


def col(frame: pd.DataFrame, name: str | None) -> np.ndarray:
    if name is None or name not in frame:
        return np.full(len(frame), np.nan)
    return np.asarray(frame[name].to_numpy(dtype=np.float64, na_value=np.nan), dtype=np.float64)


def flag(frame: pd.DataFrame, name: str, ok: np.ndarray) -> np.ndarray:
    return np.asarray(ok & frame[name].fillna(False).to_numpy(dtype=bool), dtype=bool)


def subset(o: Outcome, crows: np.ndarray, frows: np.ndarray, label: str) -> Outcome:
    """The outcome restricted to rows of the clean and faulty frames."""
    return Outcome(o.name, o.family, o.point, label, o.clean_alarm[crows], o.clean_ran[crows], o.fault_alarm[frows],
                   o.fault_ran[frows], o.onset_est[frows], None if o.alarm_angle is None else o.alarm_angle[frows], o.threshold, o.note)


# ---------------------------------------------------------------------------------------------
# One generator x cell


@dataclass
class Context:
    n: int
    n_peer: int
    run_config: dict[str, Any]
    defaults: dict[str, Any]
    opt_in: dict[str, bool]
    settings: PeerSettings
    ex: ProcessPoolExecutor
    say: Callable[[str], None]
    peers: bool = True


def cell_sizes(n: int, n_peer: int, cell: Cell) -> tuple[int, int]:
    """Curves per set, and per set for the peers, in a cell: above 2 kHz a curve has rate/2 kHz
    times the samples (and Pelt's cost grows faster), so such a cell gets a third of the curves
    and the peers a fifth, to keep a full run within about half an hour on 2 cores."""
    if cell.rate_hz <= 2000.0:
        return n, n_peer
    return max(1, n // 3), max(1, min(n // 3, n_peer // 5))


def evaluate_cell(ctx: Context, generator: str, cell: Cell, seeds: dict[str, int]) -> dict[str, Any]:
    """Calibrate ours and the peers on one clean set, evaluate on another clean set and a faulty
    set; return the scores, the outcomes and the frames."""
    ctx = replace(ctx, **dict(zip(("n", "n_peer"), cell_sizes(ctx.n, ctx.n_peer, cell))))
    t_start = time.perf_counter()
    timing: dict[str, float] = {}
    t0 = time.perf_counter()
    cal_curves, cal_truth = generate(generator, cell, ctx.n, seeds["calibration"], faulty=False)
    timing["generate_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    cal = detect(cal_curves, cal_truth, ctx.run_config, {})
    timing["detect_s"] = time.perf_counter() - t0
    ok_cal = (cal["status"] == "ok").to_numpy()
    matched_thr: dict[str, float] = {}
    statistic_choice: dict[str, list[dict[str, Any]]] = {}
    reruns: dict[str, dict[str, Any]] = {}
    dets: list[OurDetector] = []
    for d in discover(list(cal.columns)):
        if not d.candidates:
            dets.append(d)
            continue
        d, matched_thr[d.name], statistic_choice[d.name] = choose_statistic(cal, d, ok_cal)
        dets.append(d)
        key = MATCHED_RERUN_KEYS.get(d.name)
        if key in ctx.defaults and d.sign > 0 and math.isfinite(matched_thr[d.name]):
            reruns[d.name] = {**ctx.run_config, **{k: False for k in ctx.opt_in}, key: matched_thr[d.name]}
    sets: dict[str, tuple[pa.Table, pd.DataFrame]] = {}
    frames: dict[str, pd.DataFrame] = {}
    for name, faulty in (("clean", False), ("faulty", True)):
        t0 = time.perf_counter()
        sets[name] = generate(generator, cell, ctx.n, seeds[name], faulty=faulty)
        timing["generate_s"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        frames[name] = detect(*sets[name], ctx.run_config, reruns)
        timing["detect_s"] += time.perf_counter() - t0
    cf, ff = frames["clean"], frames["faulty"]
    ok_c, ok_f = (cf["status"] == "ok").to_numpy(), (ff["status"] == "ok").to_numpy()

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
        alarm_at: np.ndarray | None
        if d.name in reruns:
            m_alarm = flag(ff, f"matched_{d.alarm}", ok_f)
            rerun_agreement[d.name] = float((m_alarm == fa).mean())
            onset = np.where(fa, col(ff, f"matched_{d.angle}"), np.nan)
            alarm_at = np.where(fa, col(ff, f"matched_{d.alarm_angle}"), np.nan) if d.alarm_angle else None
        else:
            # A change angle of the configured run where it exists; an alarm angle depends on
            # the threshold, so it is left out ("-").
            alarm_at = None
            onset = np.where(fa, col(ff, d.angle), np.nan) if d.angle != d.alarm_angle else np.full(len(ff), np.nan)
        ours.append(Outcome(d.name, "ours", "matched 1 %", "all", ca, ok_c, fa, ok_f, onset, alarm_at, thr * d.sign, note))
    ours.append(Outcome("decision rule", "decision", "configured", "all", flag(cf, "change_detected", ok_c), ok_c,
                        flag(ff, "change_detected", ok_f), ok_f, col(ff, "change_angle"), None))

    # --- peers on the first n_peer curves of each set ---------------------------------------
    peers: list[Outcome] = []
    peer_info: dict[str, Any] = {}
    n_peer = min(ctx.n_peer, ctx.n) if ctx.peers else 0
    if n_peer:
        t0 = time.perf_counter()
        ex, s = ctx.ex, ctx.settings
        win = {name: peer_windows(c, t["true_window_start"].to_numpy(), t["true_window_end"].to_numpy(), range(n_peer), 0)
               for name, (c, t) in (("calibration", (cal_curves, cal_truth)), ("clean", sets["clean"]), ("faulty", sets["faulty"]))}
        stats = {name: pool_map(ex, peer_statistics, [(c, s) for c in w]) for name, w in win.items()}
        checks = pool_map(ex, check_linear_cost, [(c, s, i) for i, c in enumerate(win["calibration"][:10])])

        def peer_stat(rows: list[dict[str, Any]], name: str) -> np.ndarray:
            v = [r.get(name) for r in rows]
            return np.array([-np.inf if x is None else (x[0] if isinstance(x, tuple) else x) for x in v], dtype=np.float64)

        thr_peer = {k: calibrate(peer_stat(stats["calibration"], k)) for k in ("binseg_linear", "binseg_l2_rate", "pagehinkley", "adwin", "ols_cusum")}
        pelt_pen: dict[str, float] = {}
        pelt_runs: dict[str, int] = {}
        for which, seed_stat in (("pelt_linear", "binseg_linear"), ("pelt_l2_rate", "binseg_l2_rate")):
            start = 0.5 * thr_peer[seed_stat] if math.isfinite(thr_peer[seed_stat]) and thr_peer[seed_stat] > 0 else 10.0
            pelt_pen[which], pelt_runs[which], _ = calibrate_pelt(ex, win["calibration"], s, which, start)
        adwin_delta = 10.0 ** (-thr_peer["adwin"]) if math.isfinite(thr_peer["adwin"]) else 10.0 ** ADWIN_LOG10_RANGE[1]
        evals: dict[str, dict[str, Any]] = {}
        for name in ("clean", "faulty"):
            e: dict[str, Any] = {w: pool_map(ex, pelt_fires, [(c, s, w, pelt_pen[w]) for c in win[name]]) for w in ("pelt_linear", "pelt_l2_rate")}
            e["stream"] = pool_map(ex, peer_streaming, [(c, s, thr_peer["pagehinkley"], adwin_delta) for c in win[name]])
            evals[name] = e
        ran_c = np.array([r["ran"] for r in stats["clean"]], dtype=bool)
        ran_f = np.array([r["ran"] for r in stats["faulty"]], dtype=bool)
        for k in ("binseg_linear", "binseg_l2_rate", "ols_cusum"):
            thr = thr_peer[k]
            sc, sf = peer_stat(stats["clean"], k), peer_stat(stats["faulty"], k)
            loc = np.array([r[k][1] if k in r else np.nan for r in stats["faulty"]])
            fa = sf > thr
            peers.append(Outcome(k, "peer", "matched 1 %", "peer", sc > thr, ran_c, fa, ran_f, np.where(fa, loc, np.nan), None, thr))
        for k in ("pelt_linear", "pelt_l2_rate"):
            fa = np.array([r[1] for r in evals["faulty"][k]], dtype=bool)
            peers.append(Outcome(k, "peer", "matched 1 %", "peer", np.array([r[1] for r in evals["clean"][k]], dtype=bool), ran_c, fa,
                                 ran_f, np.array([r[2] for r in evals["faulty"][k]]), None, pelt_pen[k]))
        for k in ("pagehinkley", "adwin"):
            sf_ = evals["faulty"]["stream"]
            fa = np.array([k in r for r in sf_], dtype=bool)
            peers.append(Outcome(k, "peer", "matched 1 %", "peer", np.array([k in r for r in evals["clean"]["stream"]], dtype=bool), ran_c,
                                 fa, ran_f, np.array([r[k][1] if k in r else np.nan for r in sf_]),
                                 np.array([r[k][0] if k in r else np.nan for r in sf_]), thr_peer[k] if k == "pagehinkley" else adwin_delta))
        peer_info = {
            "thresholds": {**{f"{k}": v for k, v in thr_peer.items()}, "ols_cusum_p_value": 10.0 ** -thr_peer["ols_cusum"],
                           "adwin_delta": adwin_delta, **{f"{k}_penalty": v for k, v in pelt_pen.items()}},
            "pelt_calibration_runs": pelt_runs,
            "linear_cost_check": {"max_rel_diff": max((c[0] for c in checks), default=0.0), "curves": sum(c[1] for c in checks),
                                  "binseg_same_break": sum(c[2] for c in checks)},
        }
        timing["peers_s"] = time.perf_counter() - t0

    # --- scores ----------------------------------------------------------------------------
    # Recall only over faulty curves whose change the bolt reached.
    elig = ff["true_onset_reached"].to_numpy(bool)
    all_c = np.arange(len(cf))
    ffe = ff[elig].reset_index(drop=True)
    ours_e = [subset(o, all_c, elig, "all") for o in ours]
    groups: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for s_ in STRATEGIES:
        groups[s_] = ((cf["true_strategy"] == s_).to_numpy(), (ffe["true_strategy"] == s_).to_numpy())
    for k_ in FAULT_KINDS:
        groups[k_] = (np.zeros(len(cf), dtype=bool), (ffe["true_fault_kind"] == k_).to_numpy())
    # Breakdowns by strategy and kind for the decision rule and the matched rates (the
    # configured rates of single detectors are in the overall rows only: the JSON stays small).
    scores_all = [score(o, cf, ffe, groups if o.family == "decision" or o.point != "configured" else None) for o in ours_e]
    scores_same: list[dict[str, Any]] = []
    same_outcomes: list[Outcome] = []
    ffp = ffe.iloc[:0]
    if n_peer:
        pc_rows = np.arange(n_peer)
        pf_rows = np.flatnonzero(elig[:n_peer])
        ffp = ff.iloc[pf_rows].reset_index(drop=True)
        cfp = cf.iloc[pc_rows].reset_index(drop=True)
        same_outcomes = [subset(o, pc_rows, pf_rows, "peer") for o in ours] + [subset(o, pc_rows, pf_rows, "peer") for o in peers]
        pgroups = {s_: ((cfp["true_strategy"] == s_).to_numpy(), (ffp["true_strategy"] == s_).to_numpy()) for s_ in STRATEGIES}
        scores_same = [score(o, cfp, ffp, pgroups if o.family != "ours" or o.point != "configured" else None) for o in same_outcomes]
    status_counts = {name: {str(k): int(v) for k, v in fr["status"].astype(str).str.split(":").str[0].value_counts().items()}
                     for name, fr in (("calibration", cal), ("clean", cf), ("faulty", ff))}
    timing["total_s"] = time.perf_counter() - t_start
    return {
        "generator": generator, "cell": asdict(cell), "seeds": seeds, "n_per_set": ctx.n, "n_peer_per_set": n_peer,
        "faulty_onset_not_reached": int((~elig).sum()), "faulty_scored": int(elig.sum()),
        "median_samples": float(np.median(cf["true_n_samples"])),
        "status_counts": status_counts,
        "matched_thresholds_ours": {d.name: matched_thr[d.name] * d.sign for d in dets if d.name in matched_thr},
        "matched_statistic_choice": statistic_choice, "rerun_agreement": rerun_agreement,
        "peers": peer_info, "ours_all_curves": scores_all, "same_curves": scores_same, "runtime_s": timing,
        "_outcomes_all": ours_e, "_outcomes_same": same_outcomes, "_ff": ffe, "_ffp": ffp,
    }


# ---------------------------------------------------------------------------------------------
# Output


def find(scores: list[dict[str, Any]], name: str, point: str | None = None) -> dict[str, Any] | None:
    return next((s for s in scores if s["name"] == name and (point is None or s["point"] == point)), None)


def goal_row(s: dict[str, Any] | None) -> dict[str, Any]:
    """The four goals of issue 11 item 2 for one scored outcome: value and PASS/MISS on the point
    estimate (FA out of sample; recall over faulty curves whose change the bolt reached)."""
    if s is None:
        return {}
    fa, rl, rs = s["false_alarm"]["rate"], s["recall_ge15"]["rate"], s["recall_lt15"]["rate"]
    oe = s["onset_abs_err_median_abrupt_deg"]
    return {
        "fa": {"value": fa, "ci95": s["false_alarm"]["ci95"], "n": s["false_alarm"]["n"], "pass": fa is not None and fa <= GOAL_FA},
        "recall_15_45": {"value": rl, "ci95": s["recall_ge15"]["ci95"], "n": s["recall_ge15"]["n"], "pass": rl is not None and rl >= GOAL_RECALL_LARGE},
        "recall_3_15": {"value": rs, "ci95": s["recall_lt15"]["ci95"], "n": s["recall_lt15"]["n"], "pass": rs is not None and rs >= GOAL_RECALL_SMALL},
        "onset_abrupt_deg": {"value": oe, "n": s["onset_n_abrupt"], "pass": oe is not None and oe <= GOAL_ONSET_ABRUPT_DEG},
    }


def fmt_goal(g: dict[str, Any], key: str) -> str:
    if not g:
        return "-"
    v = g[key]
    txt = deg(v["value"]) if key == "onset_abrupt_deg" else (pct(v["value"], 2) if key == "fa" else pct(v["value"], 1))
    return f"{txt} {'PASS' if v['pass'] else 'MISS'}"


def peer_figs(s: dict[str, Any] | None) -> str:
    if s is None:
        return "-"
    return (f"{pct(s['false_alarm']['rate'], 1)} / {pct(s['recall_ge15']['rate'], 1)} / {pct(s['recall_lt15']['rate'], 1)} / "
            f"{deg(s['onset_abs_err_median_abrupt_deg'])}")


def not_ok(counts: dict[str, int]) -> str:
    """Statuses other than ok, e.g. ``model_misfit 100, too_short 2`` (``0`` if none)."""
    return ", ".join(f"{k} {v}" for k, v in counts.items() if k != "ok") or "0"


def markdown(cells: list[dict[str, Any]], meta: dict[str, Any]) -> str:
    """The tables the READMEs include (generated: never typed)."""
    lines = [
        f"Generated by `benches/detection_quality.py` on {meta['timestamp']} ({meta['command']}; {meta['wall_s'] / 60:.0f} min). "
        f"Per generator x cell: N calibration + N clean + N faulty curves (N = {meta['n']}; above 2 kHz {cell_sizes(meta['n'], meta['n_peer'], CELLS[-1])[0]}) (all strategies and fault kinds, "
        f"|change of mu| 3-45 %, either sign); peers on the first {meta['n_peer']} of each set (above 2 kHz {cell_sizes(meta['n'], meta['n_peer'], CELLS[-1])[1]}), given the TRUE elastic window. "
        f"Decision rule: default config, alpha 0.01, not recalibrated; FA out of sample; not-ok statuses count as misses. "
        f"Goals (issue 11 item 2): FA <= {GOAL_FA:.0%}, recall >= {GOAL_RECALL_LARGE} on 15-45 %, >= {GOAL_RECALL_SMALL} on 3-15 %, "
        f"median abrupt onset error <= {GOAL_ONSET_ABRUPT_DEG} deg; PASS/MISS on the point estimate.",
        "",
        "| generator | cell | curves per set (peers) | decision rule FA % | recall 15-45 % | recall 3-15 % | abrupt onset err [deg] | "
        f"{BEST_PEER} (true window, matched 1 %): FA / 15-45 / 3-15 % / onset deg | faulty (clean) curves with a status not ok |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for c in cells:
        g = goal_row(find(c["ours_all_curves"], "decision rule"))
        lines.append(f"| {c['generator']} | {c['cell']['name']} | {c['n_per_set']} ({c['n_peer_per_set']}) | {fmt_goal(g, 'fa')} | {fmt_goal(g, 'recall_15_45')} | "
                     f"{fmt_goal(g, 'recall_3_15')} | {fmt_goal(g, 'onset_abrupt_deg')} | {peer_figs(find(c['same_curves'], BEST_PEER))} | "
                     f"{not_ok(c['status_counts']['faulty'])} ({not_ok(c['status_counts']['clean'])}) |")
    band_names = [f"{100 * lo:g}-{100 * hi:g}%" for lo, hi in BANDS]
    lines += ["", "Decision rule, recall [%] by |change of mu| per strategy and by onset position in the true window (thirds):", "",
              "| generator | cell | strategy | FA % | " + " | ".join(band_names) + " | onset early | middle | late |",
              "|---|---|---|---|" + "---|" * (len(band_names) + 3)]
    for c in cells:
        s = find(c["ours_all_curves"], "decision rule")
        if s is None:
            continue
        for gname, blk in [("all", s)] + [(k, s["groups"][k]) for k in STRATEGIES]:
            lines.append(f"| {c['generator']} | {c['cell']['name']} | {gname} | {pct(blk['false_alarm']['rate'], 2)} | "
                         + " | ".join(pct(v["rate"]) for v in blk["recall_by_band"].values()) + " | "
                         + " | ".join(pct(blk["recall_by_onset_third"][t]["rate"]) for t, _, _ in ONSET_THIRDS) + " |")
    lines += ["", "Same curves (the peers' subsample), matched 1 % unless said: FA % / recall 15-45 % / recall 3-15 % / median abrupt onset error [deg]:", ""]
    names = ["decision rule"] + [n for n in ("break", "cusum", "kde", "pf", "l1", "shewhart") if any(find(c["same_curves"], n, "matched 1 %") for c in cells)] + PEER_NAMES
    lines += ["| generator | cell | " + " | ".join(names) + " |", "|---|---|" + "---|" * len(names)]
    for c in cells:
        row = []
        for nm in names:
            s = find(c["same_curves"], nm, None if nm == "decision rule" else "matched 1 %")
            row.append(peer_figs(s))
        lines.append(f"| {c['generator']} | {c['cell']['name']} | " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


def rounded(x: Any) -> Any:
    """Floats to 5 significant digits, recursively (the JSON is committed: keep it small)."""
    if isinstance(x, float):
        return x if x == 0 or not math.isfinite(x) else float(f"{x:.5g}")
    if isinstance(x, dict):
        return {k: rounded(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [rounded(v) for v in x]
    return x


def dump_json(record: dict[str, Any]) -> str:
    """Compact JSON, one line per top-level key (readable diffs, small file)."""
    items = [f"{json.dumps(k)}:{json.dumps(rounded(v), separators=(',', ':'), default=float)}" for k, v in record.items()]
    return "{\n" + ",\n".join(items) + "\n}\n"


def rewrite_block(path: Path, md: str) -> bool:
    """Replace the text between the markers in ``path``; False (and the file left alone) unless
    each marker is there exactly once, begin before end."""
    text = path.read_text()
    if text.count(BEGIN) != 1 or text.count(END) != 1 or text.index(BEGIN) > text.index(END):
        return False
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    path.write_text(f"{head}{BEGIN}\n{md}{END}{tail}")
    return True


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=None, help="curves per set (calibration, clean, faulty) per generator x cell (default 1500; --quick 300)")
    ap.add_argument("--peer-n", type=int, default=None, help="curves per set handed to the peers (default 300; --quick 100)")
    ap.add_argument("--quick", action="store_true", help="small smoke run: cells white and AR(1) 0.85, small sets (a few minutes)")
    ap.add_argument("--cells", type=str, default=None, help=f"comma-separated cell names (default all: {', '.join(c.name for c in CELLS)})")
    ap.add_argument("--generators", type=str, default=",".join(GENERATORS))
    ap.add_argument("--no-peers", action="store_true", help="ours only (a faster look)")
    ap.add_argument("--seed", type=int, default=20261126, help="base seed: cell k of generator g uses base + 1000 g + 10 k (+0 calibration, +1 clean, +2 faulty)")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="processes for the peers")
    ap.add_argument("--pelt-jump", type=int, default=5, help="Pelt's grid step in samples (ruptures' default 5)")
    ap.add_argument("--json", type=Path, default=JSON_PATH)
    ap.add_argument("--md", type=Path, default=MD_PATH)
    ap.add_argument("--plot", type=str, default=str(PLOT_PATH), help="recall against magnitude (an empty string: no plot)")
    ap.add_argument("--write-readme", action="store_true", help="rewrite the detection_quality block of README.md and benches/README.md")
    ap.add_argument("--from-json", type=Path, default=None, help="no run: write the markdown (and with --write-readme the README blocks) from a saved JSON")
    args = ap.parse_args()
    if args.from_json is not None:
        saved = json.loads(args.from_json.read_text())
        md = markdown(saved["cells"], saved.get("markdown_meta") or {
            "timestamp": saved["timestamp"], "n": saved["n_per_set"], "n_peer": saved["n_peer_per_set"], "wall_s": saved["runtime_s"]["total_s"],
            "command": "python benches/detection_quality.py " + " ".join(
                f"--{k.replace('_', '-')} {v}" for k, v in saved["args"].items() if k in ("n", "peer_n") and v is not None)
            + (" --write-readme" if saved["args"].get("write_readme") else "")})
        args.md.write_text(md)
        print(f"written: {args.md}")
        if args.write_readme:
            for path in README_BLOCKS:
                print(f"{path}: block {'rewritten' if rewrite_block(path, md) else 'markers not found or repeated, left alone'}")
        return 0
    n = args.n if args.n is not None else (300 if args.quick else 1500)
    n_peer = min(n, args.peer_n if args.peer_n is not None else (100 if args.quick else 300))
    wanted = [c.strip() for c in args.cells.split(",")] if args.cells else [c.name for c in CELLS if not args.quick or c.name in QUICK_CELLS]
    unknown = set(wanted) - {c.name for c in CELLS}
    if unknown:
        ap.error(f"unknown cells: {sorted(unknown)}")
    cells = [c for c in CELLS if c.name in wanted]
    generators = [g.strip() for g in args.generators.split(",")]
    if set(generators) - set(GENERATORS):
        ap.error(f"generators are {GENERATORS}")

    from rich.console import Console
    from rich.table import Table

    console = Console(width=220, markup=False, highlight=False)
    started = time.perf_counter()

    def say(msg: str) -> None:
        console.print(f"[{time.perf_counter() - started:7.1f} s] {msg}", highlight=False)

    if _core.DEBUG_BUILD:
        console.print("warning: tightscan._core is a debug build")
    busy_before = cpu_busy()
    defaults = _core.default_config()
    settings = PeerSettings(
        min_samples=int(defaults["zone_min_samples"]), max_windows=int(defaults["max_blocks"]),
        min_window=int(defaults["min_block_samples"]), burn_in=int(defaults["min_training_blocks"]),
        ph_delta=float(defaults["kappa"]), pelt_jump=args.pelt_jump,
    )
    probe = tightscan.detect_batch(tightscan.simulate(20, seed=args.seed)[0])
    assert isinstance(probe, pa.Table)
    opt_in = {d.name: True for d in discover(probe.column_names) if defaults.get(d.name) is False}
    run_config = {**defaults, **opt_in}
    say(f"{len(generators)} generators x {len(cells)} cells, {n} curves per set (calibration, clean, faulty), peers on the first "
        f"{n_peer if not args.no_peers else 0} of each" + (f"; opt-in detectors switched on: {', '.join(opt_in)}" if opt_in else ""))

    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    results: list[dict[str, Any]] = []
    with ProcessPoolExecutor(max_workers=args.workers, mp_context=mp.get_context("spawn")) as ex:
        ctx = Context(n, n_peer, run_config, defaults, opt_in, settings, ex, say, peers=not args.no_peers)
        for gi, generator in enumerate(GENERATORS):
            if generator not in generators:
                continue
            for k, cell in enumerate(CELLS):
                if cell not in cells:
                    continue
                base = args.seed + 1000 * gi + 10 * k
                r = evaluate_cell(ctx, generator, cell, {"calibration": base, "clean": base + 1, "faulty": base + 2})
                results.append(r)
                dr = goal_row(find(r["ours_all_curves"], "decision rule"))
                bp = find(r["same_curves"], BEST_PEER)
                say(f"{generator:11s} {cell.name:15s} ({r['runtime_s']['total_s']:5.0f} s, median {r['median_samples']:.0f} samples): "
                    f"rule FA {fmt_goal(dr, 'fa')}, 15-45 {fmt_goal(dr, 'recall_15_45')}, 3-15 {fmt_goal(dr, 'recall_3_15')}, "
                    f"onset {fmt_goal(dr, 'onset_abrupt_deg')}; {BEST_PEER}: {peer_figs(bp)}")
    wall = time.perf_counter() - started

    # --- print ---------------------------------------------------------------------------------
    console.rule("tightscan detection-quality benchmark: both generators, the noise grid")
    console.print(
        f"{n} curves per set per generator x cell (calibration / clean / faulty, distinct seeds), peers on the first "
        f"{n_peer if not args.no_peers else 0} of each (cells above 2 kHz: {cell_sizes(n, n_peer, CELLS[-1])}, see cell_sizes); thresholds of ours (matched 1 %) and of the peers set on the cell's "
        f"calibration set; FA on the clean set (out of sample). Peers get the true elastic window (recorded speed >= {STOP_RPM:g} rpm). "
        f"Decision rule at its configured alpha. Faulty curves whose onset was never reached are left out of recall.")
    for r in results:
        title = f"{r['generator']} / {r['cell']['name']}"
        console.print(f"\n{title}: {r['n_per_set']} curves per set, peers on {r['n_peer_per_set']}; statuses {r['status_counts']}; faulty scored {r['faulty_scored']} "
                      f"({r['faulty_onset_not_reached']} onsets never reached)")
        if r["same_curves"]:
            print_tables(console, f"{title}, same curves ({r['n_peer_per_set']} clean, {r['n_peer_per_set']} faulty): ours vs peers", r["same_curves"])
        print_tables(console, f"{title}, ours on all curves ({r['n_per_set']} clean, {r['faulty_scored']} faulty)", r["ours_all_curves"])
    t = Table(title="Decision rule by strategy: FA % and recall [%] by |change| and by onset third", title_justify="left")
    for h in ["generator", "cell", "strategy", "FA %", *[f"{100 * lo:g}-{100 * hi:g}" for lo, hi in BANDS], "early", "middle", "late",
              "abrupt", "incip.", "interm.", "onset err abrupt"]:
        t.add_column(h)
    for r in results:
        s = find(r["ours_all_curves"], "decision rule")
        assert s is not None
        for g in ("all", *STRATEGIES):
            blk = s if g == "all" else s["groups"][g]
            t.add_row(r["generator"], r["cell"]["name"], g, pct(blk["false_alarm"]["rate"], 2),
                      *[pct(v["rate"]) for v in blk["recall_by_band"].values()],
                      *[pct(blk["recall_by_onset_third"][name]["rate"]) for name, _, _ in ONSET_THIRDS],
                      *[pct(v["rate"]) for v in blk["recall_by_kind"].values()], deg(blk["onset_abs_err_median_abrupt_deg"]))
    console.print(t)
    t = Table(title="Decision rule by fault kind: recall [%] by |change|", title_justify="left")
    for h in ["generator", "cell", "kind", *[f"{100 * lo:g}-{100 * hi:g}" for lo, hi in BANDS], "early", "middle", "late", "onset err"]:
        t.add_column(h)
    for r in results:
        s = find(r["ours_all_curves"], "decision rule")
        assert s is not None
        for g in FAULT_KINDS:
            blk = s["groups"][g]
            t.add_row(r["generator"], r["cell"]["name"], g, *[pct(v["rate"]) for v in blk["recall_by_band"].values()],
                      *[pct(blk["recall_by_onset_third"][name]["rate"]) for name, _, _ in ONSET_THIRDS], deg(blk["onset_abs_err_median_all_deg"]))
    console.print(t)
    t = Table(title=f"Goals of issue 11 item 2 (decision rule, all curves of the cell) beside {BEST_PEER} (true window, matched 1 %, peer subsample)",
              title_justify="left")
    for h in ["generator", "cell", f"FA <= {GOAL_FA:.0%}", f"recall 15-45 >= {GOAL_RECALL_LARGE}", f"recall 3-15 >= {GOAL_RECALL_SMALL}",
              f"onset abrupt <= {GOAL_ONSET_ABRUPT_DEG} deg", f"{BEST_PEER}: FA / 15-45 / 3-15 / onset"]:
        t.add_column(h)
    goals_out = []
    for r in results:
        g = goal_row(find(r["ours_all_curves"], "decision rule"))
        goals_out.append({"generator": r["generator"], "cell": r["cell"]["name"], "decision_rule": g,
                          BEST_PEER: goal_row(find(r["same_curves"], BEST_PEER))})
        t.add_row(r["generator"], r["cell"]["name"], *[fmt_goal(g, k) for k in ("fa", "recall_15_45", "recall_3_15", "onset_abrupt_deg")],
                  peer_figs(find(r["same_curves"], BEST_PEER)))
    console.print(t)
    met = sum(v["pass"] for gr in goals_out for v in gr["decision_rule"].values())
    total = sum(len(gr["decision_rule"]) for gr in goals_out)
    console.print(f"decision rule: {met} of {total} goal checks PASS (point estimates; 95 % Wilson intervals in the JSON)")
    console.print(f"wall {wall:.0f} s; " + ", ".join(f"{r['generator']}/{r['cell']['name']} {r['runtime_s']['total_s']:.0f} s" for r in results)
                  + (f"; {busy_before:.0%} of the CPUs busy before the run" if busy_before is not None else ""))

    # --- save ----------------------------------------------------------------------------------
    ref = next((r for r in results if (r["generator"], r["cell"]["name"]) == REFERENCE), results[0] if results else None)
    edges = np.round(np.arange(MAGNITUDE_RANGE[0], MAGNITUDE_RANGE[1] + 1e-9, 0.03), 4)
    band_edges = np.array([BANDS[0][0]] + [hi for _, hi in BANDS])
    by_cell: list[dict[str, Any]] = []
    for r in results:
        for outs, ff, fam_filter in ((r["_outcomes_all"], r["_ff"], None), (r["_outcomes_same"], r["_ffp"], "peer")):
            for o in outs:
                if fam_filter == "peer" and o.family != "peer":
                    continue
                for strat in ("all", *STRATEGIES):
                    sel = np.ones(len(ff), dtype=bool) if strat == "all" else (ff["true_strategy"] == strat).to_numpy()
                    mag = ff["true_magnitude"].abs().to_numpy()
                    rec, cnt = [], []
                    for j in range(len(BANDS)):
                        m = sel & (mag >= band_edges[j]) & ((mag <= band_edges[j + 1]) if j == len(BANDS) - 1 else (mag < band_edges[j + 1]))
                        rec.append(float(o.fault_alarm[m].mean()) if m.any() else None)
                        cnt.append(int(m.sum()))
                    by_cell.append({"generator": r["generator"], "cell": r["cell"]["name"], "strategy": strat, "detector": o.name,
                                    "point": o.point, "family": o.family, "subset": "peer" if o.family == "peer" else "all",
                                    "recall": rec, "n": cnt})
    meta = {"timestamp": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "n": n, "n_peer": n_peer if not args.no_peers else 0,
            "wall_s": wall, "command": "python benches/detection_quality.py " + " ".join(sys.argv[1:])}
    record: dict[str, Any] = {
        "timestamp": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "args": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
        "n_per_set": n, "n_peer_per_set": n_peer if not args.no_peers else 0,
        "generators": generators, "cells_run": [asdict(c) for c in cells], "reference_cell": list(REFERENCE),
        "magnitude_range": MAGNITUDE_RANGE, "bands": BANDS, "onset_thirds": ONSET_THIRDS, "fa_target": FA_TARGET,
        "goal_thresholds": {"fa": GOAL_FA, "recall_15_45": GOAL_RECALL_LARGE, "recall_3_15": GOAL_RECALL_SMALL, "onset_abrupt_deg": GOAL_ONSET_ABRUPT_DEG},
        "goals": goals_out,
        "opt_in_switched_on": list(opt_in),
        "peer_settings": settings.__dict__,
        "config_ours": dict(run_config),
        "cells": [{k: v for k, v in r.items() if not k.startswith("_")} for r in results],
        "markdown_meta": meta,
        "runtime_s": {"total_s": wall},
        "cpu_busy_before": busy_before, "cpus": os.cpu_count(), "workers": args.workers,
        "platform": platform.platform(), "python": platform.python_version(),
        "versions": {m: __import__(m).__version__ for m in ("numpy", "pyarrow", "ruptures", "river", "statsmodels", "scipy")},
    }
    if ref is not None:
        # The keys of the single-cell benchmark, for the reference cell.
        record.update({
            "seeds": ref["seeds"], "status_counts": ref["status_counts"], "same_curves": ref["same_curves"],
            "ours_all_curves": ref["ours_all_curves"], "matched_thresholds_ours": ref["matched_thresholds_ours"],
            "matched_statistic_choice": ref["matched_statistic_choice"], "peer_thresholds": ref["peers"].get("thresholds", {}),
        })
        panel_same = [o for o in ref["_outcomes_same"] if o.point.startswith("matched")]
        panel_all = [o for o in ref["_outcomes_all"] if o.point.startswith("matched") or o.family == "decision"]
        record["recall_vs_magnitude"] = {
            "edges": edges.tolist(),
            "same_curves": {f"{o.name} ({o.point})": recall_curve(o, ref["_ffp"], edges) for o in panel_same},
            "ours_all_curves": {f"{o.name} ({o.point})": recall_curve(o, ref["_ff"], edges) for o in panel_all},
            "band_edges": band_edges.tolist(), "by_cell": by_cell,
        }
        if args.plot:
            whites = [r for r in results if r["cell"]["name"] == "white"] or [ref]
            panels: list[tuple[str, list[Outcome], pd.DataFrame]] = []
            for r in whites:
                panels.append((f"{r['generator']} / white: ours on {len(r['_ff'])} faulty curves",
                               [o for o in r["_outcomes_all"] if o.point.startswith("matched") or o.family == "decision"], r["_ff"]))
                if r["_outcomes_same"]:
                    panels.append((f"{r['generator']} / white: same {len(r['_ffp'])} faulty curves, peers given the true window",
                                   [o for o in r["_outcomes_same"] if o.point.startswith("matched") or o.family == "decision"], r["_ffp"]))
            plot(Path(args.plot), panels, edges)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(dump_json(record))
    md = markdown(results, meta)
    args.md.write_text(md)
    console.print(f"written: {args.json}, {args.md}" + (f", {args.plot}" if args.plot else ""))
    if args.write_readme:
        for path in README_BLOCKS:
            console.print(f"{path}: block {'rewritten' if rewrite_block(path, md) else 'markers not found or repeated, left alone'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
