"""End-to-end size and power on the simulator (the exact size and delay checks against Monte
Carlo and Siegmund are Rust tests in crates/tightscan-core/src/{cusum,detect}.rs)."""

from __future__ import annotations

import numpy as np
import pyarrow as pa

import tightscan


def _detected(results: pa.Table) -> tuple[np.ndarray, np.ndarray]:
    ok = np.array([s == "ok" for s in results.column("status").to_pylist()])
    det = np.array([bool(x) for x in results.column("change_detected").to_pylist()])
    return ok, det


def test_false_alarms_on_clean_tightenings_stay_near_nominal() -> None:
    # ARL0 = 3000 blocks over <= 30 monitored blocks: <= 1 % with known parameters, ~0.9 % with
    # estimated ones (Rust test). Measured at seed 5: CST 0.4 %, CSDT 0.8 %, HDT 0.2 %. A scale
    # or pause handling that is off by the amounts seen during development (3 % - 34 %) fails.
    curves, _ = tightscan.simulate(3000, seed=5, fault_fraction=0.0)
    results = tightscan.detect_batch(curves, passthrough=["strategy"])
    ok, det = _detected(results)
    assert ok.mean() > 0.9
    strategy = np.array(results.column("strategy").to_pylist())
    for s in ("CST", "CSDT", "HDT"):
        m = ok & (strategy == s)
        assert det[m].mean() < 0.02, (s, det[m].mean())


def test_large_changes_after_the_training_window_are_found() -> None:
    curves, truth = tightscan.simulate(1500, seed=6, fault_fraction=1.0, fault_kinds=["abrupt"], magnitude_range=(0.2, 0.4))
    results = tightscan.detect_batch(curves)
    ok, det = _detected(results)
    onset = truth.column("onset_angle").to_numpy(zero_copy_only=False)
    start = results.column("elastic_start_angle").to_numpy(zero_copy_only=False)
    end = results.column("elastic_end_angle").to_numpy(zero_copy_only=False)
    width = results.column("cusum_block_angle").to_numpy(zero_copy_only=False)
    blocks = results.column("cusum_blocks").to_numpy(zero_copy_only=False)
    # Onsets inside the monitored part of the window, one block clear of the training window.
    training_end = end - blocks * width
    seen = ok & (onset > training_end + width) & (onset < end - width)
    assert seen.sum() > 300
    # Measured 0.87 at this seed. Known blind spot: blocks are fitted separately, so a torque
    # jump that falls exactly between two blocks shows only through the (smaller) rate change
    # after it; a between-block level statistic (issue 4) closes it.
    assert det[seen].mean() > 0.85
    error = np.abs(results.column("change_angle").to_numpy(zero_copy_only=False) - onset)[seen & det]
    assert np.median(error) < 2.0
