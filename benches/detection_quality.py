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
from typing import Any, Callable, Iterator, Sequence

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc

import tightscan
from _benchutil import cpu_busy
from tightscan import _core
from peers import ADWIN_LOG10_RANGE, calibrate_pelt, check_linear_cost, FA_TARGET, peer_statistics, peer_streaming, peer_windows, PeerCurve, PeerSettings, pelt_fires, pool_map, prepare, STOP_RPM
from scoring import BANDS, deg, FAULT_KINDS, GOAL_RECALL_LARGE, GOAL_RECALL_SMALL, Outcome, pct, plot, print_groups, print_tables, rate, recall_curve, score

RESULTS = Path(__file__).resolve().parent / "results"
JSON_PATH = RESULTS / "detection_quality.json"
PLOT_PATH = RESULTS / "recall_vs_magnitude.png"

STRATEGIES = ("CST", "CSDT", "HDT")
MAGNITUDE_RANGE = (0.03, 0.45)

# Goals of the detection-quality issue.
GOAL_FA = 0.01
GOAL_ONSET_ABRUPT_DEG = 0.5

# A detector whose angles are only reported when it alarms must be rerun at the matched
# threshold to give angles there: prefix -> the config key that sets its threshold in the units
# of its statistic (CUSUM h and the 3-sigma baseline's k, both in sigma). Used only if the key
# exists in the core's default config; the rerun's alarms are checked against the statistic.
MATCHED_RERUN_KEYS = {"cusum": "threshold", "shewhart": "shewhart_k"}

SIM_CHUNK = 4000  # tightenings per simulate/detect call: bounds memory (~25 MB per 1,000)


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
