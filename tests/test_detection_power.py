"""Reduced power check of the default decision rule on curves it was not calibrated on: the
independent generator (tests/independent_generator, plain numpy, written from the physics texts
without the simulator's code), white torque noise of 0.01 Nm + 0.4 % of the target (the setting
of issue 11), 2 kHz, 0.1 deg encoder, strategies CST and HDT, abrupt friction changes of either
sign. The full figures (both generators, the noise grid, peers) come from
``benches/detection_quality.py``; this keeps a floor under them in ``make test``.

A rule that never alarms fails the recall floors; one that alarms on everything fails the
false-alarm bounds (and one that alarms at random at a rate near alpha fails the recall floors).
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
import pyarrow as pa
import pytest

import independent_generator as ig
import tightscan

ALPHA = 0.01
N_CLEAN = 1500  # per strategy
N_FAULTY = 200  # per strategy and band of |change|
NOISE = ig.NoiseConfig(sd_nm=0.01, sd_rel=0.0, sd_target_rel=0.004)
Strategy = Literal["CST", "HDT"]

# Floors: a little below what was measured at these seeds (in the comments), so that they
# catch a regression of a few points, not the sampling noise of a fixed seed (which is none:
# the curves are the same every run) or of a harmless change of the rule (binomial sd of a
# recall near 0.9 over ~200 curves is about 2 points).
# Measured with the union-bound rule and the break detector's start test (before the start
# test in brackets: it finds changes in the window's first samples, which the scan cannot
# isolate; most of HDT's misses were there).
RECALL_FLOOR = {
    ("CST", "large"): 0.97,  # measured 1.000 (1.000, 200 of 200 curves)
    ("CST", "small"): 0.80,  # measured 0.850 (0.840)
    ("HDT", "large"): 0.95,  # measured 0.980 (0.900)
    ("HDT", "small"): 0.75,  # measured 0.780 (0.725)
}
# Incipient drifts (friction growing linearly from the onset to the end of the elastic zone).
# Before the misfit guard knew the drift's shape (a line that turns at the onset, by a kink
# and a parabola, engine/analysis/breaks.rs `curvature`) it called most drifts starting in the
# window's first half `model_misfit`: recall about 0.6 whatever the size. Measured with the
# drift's knots from 0.03 of the window (before, from 0.18, in brackets).
INCIPIENT_FLOOR = {
    ("CST", "large"): 0.97,  # measured 0.995 (0.960)
    ("CST", "small"): 0.87,  # measured 0.925 (0.915)
    ("HDT", "large"): 0.95,  # measured 0.985 (0.980)
    ("HDT", "small"): 0.82,  # measured 0.875 (0.865)
}
BANDS = {"large": (0.15, 0.45), "small": (0.03, 0.15)}


def _generate(strategy: Strategy, seed: int, n: int, magnitude: tuple[float, float] | None,
              kind: Literal["abrupt", "incipient"] = "abrupt") -> tuple[pa.Table, pa.Table]:
    fault = ig.FaultConfig(kind=kind, magnitude=magnitude, signed=True, acts_on="mix") if magnitude else ig.FaultConfig(kind=None)
    return ig.generate(ig.GeneratorConfig(n=n, seed=seed, strategy=strategy, sample_rate_hz=2000.0, encoder_step_deg=0.1,
                                          noise=NOISE, fault=fault))


def _detected(curves: pa.Table) -> np.ndarray:
    """change_detected per curve; no decision (a status other than ok) counts as no alarm."""
    results = tightscan.detect_batch(curves, config={"alpha": ALPHA})
    return np.array([bool(v) for v in results.column("change_detected").to_pylist()])


@pytest.mark.parametrize("strategy", ["CST", "HDT"])
@pytest.mark.parametrize("band", ["large", "small"])
def test_recall_of_abrupt_changes_on_the_independent_generator(strategy: Strategy, band: str) -> None:
    seed = {"CST": 4101, "HDT": 4102}[strategy] + (10 if band == "small" else 0)
    curves, truth = _generate(strategy, seed, N_FAULTY, BANDS[band])
    # A change the bolt never reached (the tool stopped first) is not in the curve.
    reached = np.array(truth.column("onset_reached").to_pylist(), dtype=bool)
    assert reached.sum() >= 0.8 * N_FAULTY
    recall = float(_detected(curves)[reached].mean())
    assert recall >= RECALL_FLOOR[(strategy, band)], f"{strategy} {band}: recall {recall:.3f} over {reached.sum()} curves"


@pytest.mark.parametrize("strategy", ["CST", "HDT"])
@pytest.mark.parametrize("band", ["large", "small"])
def test_recall_of_incipient_drifts_on_the_independent_generator(strategy: Strategy, band: str) -> None:
    seed = {"CST": 4301, "HDT": 4302}[strategy] + (10 if band == "small" else 0)
    curves, truth = _generate(strategy, seed, N_FAULTY, BANDS[band], kind="incipient")
    reached = np.array(truth.column("onset_reached").to_pylist(), dtype=bool)
    assert reached.sum() >= 0.8 * N_FAULTY
    recall = float(_detected(curves)[reached].mean())
    assert recall >= INCIPIENT_FLOOR[(strategy, band)], f"{strategy} {band}: recall {recall:.3f} over {reached.sum()} curves"


@pytest.fixture(scope="module")
def clean_alarms() -> np.ndarray:
    seeds: tuple[tuple[Strategy, int], ...] = (("CST", 4201), ("HDT", 4202))
    return np.concatenate([_detected(_generate(s, seed, N_CLEAN, None)[0]) for s, seed in seeds])


def test_false_alarms_of_the_default_rule_are_within_binomial_tolerance_of_alpha(clean_alarms: np.ndarray) -> None:
    # Within 3 binomial sd of alpha over 3,000 clean curves: [0.46 %, 1.54 %], 14 to 46 alarms.
    # A rule alarming on everything (or on a tenth of the curves) fails the upper bound; one
    # that never alarms fails the lower. Measured 0.80 % at these seeds (CST 0.87 %, HDT
    # 0.73 %) with the episode scan, which takes its 30 % of the break detector's alpha from
    # the scan and adds almost no alarms of its own on clean curves; 0.90 % (CST 0.93 %, HDT
    # 0.87 %) without it, with the union-bound rule and the start test (0.80 % with a tenth of alpha each
    # for it and the end test, a twentieth each now); 0.97 % before the start test (the
    # scan's share of alpha went from 90 % to 80 % of the break detector's); 1.47 % (CST
    # 1.80 %, HDT 1.13 %) with the rule calibrated to the built-in simulator it replaced.
    n = clean_alarms.size
    sd = math.sqrt(ALPHA * (1 - ALPHA) / n)
    rate = float(clean_alarms.mean())
    assert ALPHA - 3 * sd <= rate <= ALPHA + 3 * sd, f"false-alarm rate {rate:.4f} over {n} clean curves"


def _early_or_late(strategy: Strategy, onset: tuple[float, float], seed: int, n: int, noise: ig.NoiseConfig | None = NOISE) -> pa.Table:
    fault = ig.FaultConfig(kind="abrupt", magnitude=(0.15, 0.45), signed=True, acts_on="mix", onset_fraction=onset)
    config = ig.GeneratorConfig(n=n, seed=seed, strategy=strategy, sample_rate_hz=2000.0, encoder_step_deg=0.1, fault=fault,
                                **({"noise": noise} if noise is not None else {}))
    return ig.generate(config)[0]


def test_changes_in_the_window_first_samples_are_found_by_the_start_test() -> None:
    """An abrupt change at a fifth to 0.3 of the elastic zone makes the torque jump by the clamp
    force times the change: the jump is in the window's first samples (or carries the torque
    across the window's start level), where the scan, held ten samples from the window's
    start, cannot place a break. The start test (`break_head_fraction` of the break detector's
    alpha) and the two samples the window keeps before its start level find them. Measured
    at these seeds, 200 curves each: CST 1.000 (0.995 without the start test), HDT 0.970
    (0.895 with a tenth of alpha for each end test); before either, HDT 0.715."""
    for strategy, floor, ceiling in (("CST", 0.98, 1.0), ("HDT", 0.95, 0.93)):
        curves = _early_or_late(strategy, (0.2, 0.3), 41, 200)
        recall = float(_detected(curves).mean())
        assert recall >= floor, f"{strategy}: recall {recall:.3f}"
        if strategy == "HDT":
            results = tightscan.detect_batch(curves, config={"alpha": ALPHA, "break_head_fraction": 0.0})
            without = float(np.mean([bool(v) for v in results.column("change_detected").to_pylist()]))
            assert without <= ceiling, f"{strategy}: recall without the start test {without:.3f}"
            assert results.column("break_head_p_value").null_count == results.num_rows



def _intermittent(magnitude: tuple[float, float], episodes: tuple[int, int], seed: int) -> tuple[pa.Table, np.ndarray]:
    """400 curves of the independent generator (2 kHz, 0.1 deg, all strategies) with an
    intermittent fault, and which of them reached its onset."""
    fault = ig.FaultConfig(kind="intermittent", magnitude=magnitude, signed=True, acts_on="mix", episodes=episodes)
    curves, truth = ig.generate(ig.GeneratorConfig(n=400, seed=seed, strategy="mix", sample_rate_hz=2000.0, encoder_step_deg=0.1,
                                                   noise=NOISE, fault=fault))
    reached = np.array(truth.column("onset_reached").to_pylist(), dtype=bool)
    assert reached.sum() >= 0.8 * 400
    return curves, reached


def test_intermittent_episodes_are_found_by_the_episode_scan() -> None:
    """An intermittent fault of 3-10 %, one episode of 4-12 % of the elastic zone (the torque
    leaves the line for a stretch and comes back to it: a pulse, not a break), all three
    strategies. The episode scan (`break_episode_fraction` of the break detector's alpha) finds
    what the scan for one break misses. Measured at this seed, 400 curves: 0.825, 0.760 without
    the episode scan (30 curves found only with it, 4 only without; seeds 4702 and 4703: 0.825
    and 0.812 against 0.767 and 0.738), with the one-stretch scan; with up to three stretches
    0.825, 0.820 and 0.810."""
    curves, reached = _intermittent((0.03, 0.10), (1, 1), 4701)
    recall = float(_detected(curves)[reached].mean())
    results = tightscan.detect_batch(curves, config={"alpha": ALPHA, "break_episode_fraction": 0.0})
    without = float(np.array([bool(v) for v in results.column("change_detected").to_pylist()])[reached].mean())
    assert results.column("break_episode_p_value").null_count == results.num_rows
    assert recall >= 0.79, f"recall {recall:.3f}"
    assert recall - without >= 0.035, f"recall {recall:.3f}, without the episode scan {without:.3f}"


def test_an_intermittent_fault_that_comes_back_is_found_by_the_episode_scan() -> None:
    """An intermittent fault of 2-6 %, two or three episodes of 4-12 % of the elastic zone each:
    one fitted stretch leaves the others in the residuals that judge it, so the episode scan
    fits up to three (greedily, each with the ones before it fitted). Measured at this seed,
    400 curves: 0.810, 0.792 with the one-stretch scan (seed 4712: 0.782 against 0.757); the
    Rust test `several_short_episodes_are_found_more_often_than_by_one_stretch` shows the
    statistic's gain where the pulses are short (254 against 154 of 400)."""
    curves, reached = _intermittent((0.02, 0.06), (2, 3), 4711)
    recall = float(_detected(curves)[reached].mean())
    assert recall >= 0.80, f"recall {recall:.3f}"
