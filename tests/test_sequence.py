"""Monitoring across tightenings (`monitor_sequence`): size and power on synthetic groups, the
real thread-wear data, and the table handling."""

from __future__ import annotations

from collections import Counter

import numpy as np
import polars as pl
import pyarrow as pa
import pyarrow.compute as pc
import pytest

import tightscan


def _groups(n_groups: int, n: int, seed: int, shift: float, at: int) -> pa.Table:
    rng = np.random.default_rng(seed)
    values = rng.normal(1.0, 0.05, size=(n_groups, n))
    values[:, at:] += shift * 0.05
    return pa.table(
        {
            "station": np.repeat(np.arange(n_groups), n),
            "order": np.tile(np.arange(n), n_groups)[::-1].copy(),  # rows arrive in reverse order
            "torque_rate": values[:, ::-1].ravel(),
        }
    )


def test_size_and_power_per_group() -> None:
    alpha = 0.05
    clean = tightscan.monitor_sequence(_groups(2000, 120, 1, 0.0, 0), by=["station"], order_by="order",
                                       features=["torque_rate"], training=20, alpha=alpha)
    cusum = clean.groups.column("cusum_alarm_order").null_count
    l1 = clean.groups.column("l1_alarm_order").null_count
    # Self-starting CUSUM at N / ARL0 = alpha: measured 3.7-4 %; the L1 boundary is open-ended.
    assert 0.025 < 1 - cusum / 2000 <= alpha + 0.01
    assert 1 - l1 / 2000 <= alpha + 0.01
    shifted = tightscan.monitor_sequence(_groups(500, 120, 2, 1.5, 60), by=["station"], order_by="order",
                                         features=["torque_rate"], training=20, alpha=alpha)
    first = shifted.groups.column("cusum_alarm_order").to_pylist()
    assert sum(a is not None for a in first) / 500 > 0.97
    # The alarm comes after the change, and the change-start estimate lands near it.
    late = [a for a in first if a is not None]
    assert np.median(late) >= 60 and np.median(late) < 75
    starts = [s for s in shifted.groups.column("cusum_change_order").to_pylist() if s is not None]
    assert abs(np.median(starts) - 60) <= 3


def test_real_threads_wear_with_reuse(rexroth_s01: pa.Table) -> None:
    """The s01 threads, each re-used 25 times: the rundown torque of most threads drifts down."""
    results = tightscan.detect_batch(rexroth_s01, passthrough=["workpiece_id", "workpiece_location", "workpiece_usage"])
    m = tightscan.monitor_sequence(results, by=["workpiece_id", "workpiece_location"], order_by="workpiece_usage",
                                   features=["prevailing_torque"], training=5, alpha=0.05)
    groups = m.groups
    assert groups.num_rows == 200
    alarmed = groups.filter(pc.is_valid(groups.column("cusum_alarm_order")))
    # Measured: 102 of 200 threads, all on the 'decrease' side, at re-use 12-23 mostly.
    assert alarmed.num_rows > 60
    sides = Counter(alarmed.column("cusum_side").to_pylist())
    assert sides["decrease"] >= 0.95 * alarmed.num_rows
    assert np.median(alarmed.column("cusum_alarm_order").to_numpy()) >= 8


def test_polars_in_polars_out_and_errors() -> None:
    table = _groups(3, 40, 3, 0.0, 0)
    out = tightscan.monitor_sequence(pl.from_arrow(table), by=["station"], order_by="order", features=["torque_rate"])
    assert isinstance(out.groups, pl.DataFrame) and isinstance(out.tightenings, pl.DataFrame)
    assert out.tightenings.height == 120
    with pytest.raises(tightscan.SchemaError) as e:
        tightscan.monitor_sequence(table, by=["line"], features=["torque_rate"])
    assert e.value.column == "line"
    with pytest.raises(tightscan.InvalidParameterError) as p:
        tightscan.monitor_sequence(table, features=["torque_rate"], alpha=0.9)
    assert p.value.parameter == "alpha"
