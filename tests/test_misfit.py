"""Misfit is not a change: controller events inside the elastic window (a change of controller
step, a pause the recorder did not sample, a relaxation dip and wind-up) are not called friction
changes, and the real s01 control group gets few claims."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest

import tightscan

RATE = 0.075  # Nm/deg, elastic torque rate of the synthetic curves


def _curve(n: int = 600, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rundown, then a straight elastic rise; 0.25 deg and 1 ms per sample, a little noise."""
    rng = np.random.default_rng(seed)
    angle = np.arange(n) * 0.25
    torque = np.where(angle < 40.0, 0.5, 0.5 + RATE * (angle - 40.0)) + rng.normal(0.0, 0.004, n)
    time = np.arange(n) * 0.001
    return angle, torque, time


def _table(curves: list[tuple[np.ndarray, np.ndarray, np.ndarray]], **extra: pa.Array) -> pa.Table:
    lists = lambda k: pa.array([c[k] for c in curves], pa.list_(pa.float64()))  # noqa: E731
    return pa.table({"tightening_id": list(range(len(curves))), "angle": lists(0), "torque": lists(1), "time": lists(2), **extra})


def _with_relaxation(seed: int, at: int = 400, depth: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The tool nearly stops at sample `at` (0.02 deg per sample for 11 samples): the torque
    relaxes by `depth` Nm over 5 samples, then winds up again within 6, and the elastic line
    goes on."""
    rng = np.random.default_rng(seed)
    steps = np.full(600, 0.25)
    steps[at : at + 11] = 0.02
    angle = np.concatenate([[0.0], np.cumsum(steps[1:])])
    torque = np.where(angle < 40.0, 0.5, 0.5 + RATE * (angle - 40.0)) + rng.normal(0.0, 0.004, 600)
    torque[at : at + 5] -= depth * np.linspace(0.2, 1.0, 5)
    torque[at + 5 : at + 11] -= depth * np.linspace(0.8, 0.0, 6)
    return angle, torque, np.arange(600) * 0.001


def test_a_relaxation_dip_is_not_a_change() -> None:
    curves = [_with_relaxation(seed) for seed in range(20)]
    results = tightscan.detect_batch(_table(curves))
    assert results["change_detected"].to_pylist() == [False] * 20
    # The detectors test the window from where the torque has wound up again.
    assert min(results["tested_start_angle"].to_pylist()) >= 399 * 0.25


def test_a_friction_drop_is_still_found() -> None:
    # A friction decrease drops the torque at once and goes on at a lower rate: not a relaxation.
    curves = []
    for seed in range(20):
        angle, torque, time = _curve(seed=seed)
        drop = angle >= 100.0
        torque = torque - drop * 0.2 * (0.5 + RATE * (angle - 40.0) - 0.5)
        curves.append((angle, torque, time))
    results = tightscan.detect_batch(_table(curves))
    assert results["change_detected"].to_pylist() == [True] * 20


def test_an_unsampled_pause_starts_a_new_segment() -> None:
    curves = []
    for seed in range(10):
        angle, torque, time = _curve(seed=seed)
        # Flat before the pause, rising after it: one line through both would be a misfit.
        torque = np.where(angle < 75.0, 0.5 + 0.01 * (angle - 40.0).clip(0), torque)
        time = time + (angle >= 75.0) * 0.05  # the recorder stopped for 50 ms
        curves.append((angle, torque, time))
    results = tightscan.detect_batch(_table(curves))
    assert all(a >= 75.0 for a in results["tested_start_angle"].to_pylist())
    assert results["change_detected"].to_pylist() == [False] * 10


def test_the_last_controller_step_is_tested() -> None:
    angle, torque, time = _curve()
    step = (angle >= 90.0).astype(np.int32)
    table = _table([(angle, torque, time)], step=pa.array([step], pa.list_(pa.int32())))
    results = tightscan.detect_batch(table)
    assert results["tested_start_angle"][0].as_py() >= 90.0
    assert results["status"][0].as_py() == "ok"


def test_step_channel_errors() -> None:
    angle, torque, time = _curve()
    bad_type = _table([(angle, torque, time)], step=pa.array([angle], pa.list_(pa.float64())))
    with pytest.raises(tightscan.SchemaError) as err:
        tightscan.detect_batch(bad_type)
    assert err.value.column == "step"
    short = _table([(angle, torque, time)], step=pa.array([[0] * 10], pa.list_(pa.int32())))
    status = tightscan.detect_batch(short)["status"][0].as_py()
    assert status.startswith("length_mismatch: step")


def test_a_late_relaxation_dip_ends_the_tested_window() -> None:
    # The dip comes a few degrees before the window's end (the real Rexroth runs pause there):
    # too few samples follow it, so the part before it is tested, and nothing after it.
    dip_angle = 565 * 0.25
    results = tightscan.detect_batch(_table([_with_relaxation(seed, at=565) for seed in range(20)]))
    assert results["change_detected"].to_pylist() == [False] * 20
    assert results["status"].to_pylist() == ["ok"] * 20
    ends = results["tested_end_angle"].to_pylist()
    assert max(ends) < dip_angle
    assert min(ends) > dip_angle - 2.0
    assert all(e < w for e, w in zip(ends, results["elastic_end_angle"].to_pylist()))


def test_a_late_intermittent_friction_episode_is_tested_and_found() -> None:
    # Friction 20 % lower for 3 deg, late in the window: the torque falls at once and jumps back
    # at once. The two samples after the fall lie lower still (as noise puts them often), so
    # the fall spans three samples and the jump back is, on average, faster than three times
    # the elastic rate: the shape of a relaxation dip and wind-up by those two measures. The
    # window used to end before it, and the change was left untested (3 of 8 missed 15-45 %
    # changes of the built-in simulator's white-noise curves, 8 of 12 with noise growing with
    # the torque). One sample carries the fall and one the return: an episode, not a relaxation.
    curves = []
    for seed in range(10):
        angle, torque, time = _curve(seed=seed)
        drop = 0.2 * RATE * (angle - 40.0)
        torque = torque - np.select([np.arange(600) == 560, np.arange(600) == 561, (np.arange(600) >= 562) & (np.arange(600) < 572)],
                                    [drop, 1.05 * drop, 1.1 * drop], 0.0)
        curves.append((angle, torque, time))
    results = tightscan.detect_batch(_table(curves))
    assert all(e > 143.0 for e in results["tested_end_angle"].to_pylist())
    assert results["change_detected"].to_pylist() == [True] * 10


def test_a_late_unsampled_pause_ends_the_tested_window() -> None:
    curves = []
    for seed in range(10):
        angle, torque, time = _curve(seed=seed)
        # The torque relaxes by 0.3 Nm while the recorder is stopped, 6 deg before the window's end.
        torque = np.where(angle >= 140.0, torque - 0.3, torque)
        time = time + (angle >= 140.0) * 0.05
        curves.append((angle, torque, time))
    results = tightscan.detect_batch(_table(curves))
    assert results["change_detected"].to_pylist() == [False] * 10
    assert all(139.0 < e < 140.0 for e in results["tested_end_angle"].to_pylist())


def test_every_step_change_in_the_window_counts() -> None:
    # Two step changes inside the window; at the last, the torque falls and is wound up again
    # over 2 deg. The test starts where the torque is back on the elastic line, not where it
    # regains its old level (which it does half way up the wind-up).
    curves, steps = [], []
    for seed in range(10):
        angle, torque, time = _curve(seed=seed)
        step = (angle >= 80.0).astype(np.int32) + (angle >= 110.0).astype(np.int32)
        wind_up = (angle >= 110.0) & (angle < 112.0)
        torque = np.where(wind_up, torque - 0.4 * (112.0 - angle) / 2.0 * 2.0, torque)
        curves.append((angle, torque, time))
        steps.append(step)
    results = tightscan.detect_batch(_table(curves, step=pa.array(steps, pa.list_(pa.int32()))))
    assert all(s >= 111.75 for s in results["tested_start_angle"].to_pylist())
    assert results["change_detected"].to_pylist() == [False] * 10


def test_s01_control_group_claims_are_bounded(rexroth_s01: pa.Table) -> None:
    # s01 is a control group: no friction fault inside any tightening. The rule claimed a change
    # in 99.4 % of the decided runs before the noise model and the controller-event handling,
    # 8.8 % before pauses late in the window ended it and every step change counted; 1.3 %
    # (35 of 2,755) after; 0.64 % (16 of 2,501) with the noise model fitted to the rundown as
    # well (its AR order, and so the fewest samples a window needs, is higher on these
    # filtered channels); 0.28 % (7 of 2,501) with the tests averaged over the AR fit's
    # uncertainty. Goal: at most 2 %.
    results = tightscan.detect_batch(rexroth_s01)
    decided = [v for v in results["change_detected"].to_pylist() if v is not None]
    assert len(decided) >= 2450
    assert float(np.mean(decided)) <= 0.02
    # Every undecided run says why, and names the part of the window it could not test.
    statuses = results["status"].to_pylist()
    assert all(s == "ok" or s.startswith(("too_short: ", "model_misfit: ")) for s in statuses)
    assert any("before the tool paused" in s for s in statuses)
