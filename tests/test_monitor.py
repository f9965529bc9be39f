"""`monitor_regression`: the whole detector and boundary path of one series, and the L1
columns of `detect_batch`. Size and power of the procedures themselves are Rust tests
(crates/tightscan-core/src/detectors/monitor.rs) and R oracles (tests/oracles)."""

from __future__ import annotations

import numpy as np
import pytest

import tightscan


@pytest.mark.parametrize("method", ["l1", "ols_cusum"])
def test_path_and_alarm_agree(method: str) -> None:
    rng = np.random.default_rng(7)
    force = rng.uniform(5.0, 15.0, 400)
    torque = 0.3 + 0.12 * force + rng.normal(0.0, 0.05, 400)
    torque[250:] += 0.02 * force[250:]  # friction +17 % from observation 250
    m = tightscan.monitor_regression(torque, [force], training=80, method=method)  # type: ignore[arg-type]
    assert m.statistic is not None and m.boundary is not None
    assert m.monitored == 320 and m.statistic.shape == m.boundary.shape == (320,)
    crossed = np.flatnonzero(m.statistic > m.boundary)
    assert m.alarm and crossed.size > 0
    k = int(crossed[0])  # step k + 1, observation training + k
    assert m.alarm_index == 80 + k and m.alarm_index >= 250
    assert m.statistic_at_alarm == pytest.approx(m.statistic[k]) and m.boundary_at_alarm == pytest.approx(m.boundary[k])
    assert len(m.coefficients) == 2 and m.coefficients[1] == pytest.approx(0.12, rel=0.05)
    assert (m.gamma, m.alpha) == (0.25, 0.05)


def test_size_on_iid_noise() -> None:
    """1,000 in-control series (m = 50, 4 m monitored) at alpha 0.05: the open-ended procedure
    over a finite horizon is at or a little below its level (2.5 % measured)."""
    rng = np.random.default_rng(8)
    alarms = sum(tightscan.monitor_regression(rng.normal(size=250), training=50, keep_path=False).alarm for _ in range(1000))
    assert 0.015 <= alarms / 1000 <= 0.05 + 3 * np.sqrt(0.05 * 0.95 / 1000), alarms


def test_bad_method_is_named() -> None:
    with pytest.raises(tightscan.InvalidParameterError) as err:
        tightscan.monitor_regression([1.0] * 50, method="cusum")  # type: ignore[arg-type]
    assert err.value.parameter == "method"


def test_detect_batch_reports_l1_boundary_gamma_and_alpha() -> None:
    curves, _ = tightscan.simulate(300, seed=12, fault_fraction=1.0, magnitude_range=(0.3, 0.45))
    out = tightscan.detect_batch(curves, config={"l1_gamma": 0.15, "l1_alpha": 0.05}).to_pylist()
    assert {r["l1_gamma"] for r in out if r["l1_gamma"] is not None} == {0.15}
    assert {r["l1_alpha"] for r in out if r["l1_alpha"] is not None} == {0.05}
    fired = [r for r in out if r["l1_alarm"]]
    assert fired, "no L1 alarm on 300 large faults"
    for r in fired:
        assert r["l1_statistic_at_alarm"] > r["l1_boundary_at_alarm"] > 0
    assert all(r["l1_statistic_at_alarm"] is None for r in out if r["l1_alarm"] is False)


def test_critical_values_from_the_table_and_by_simulation() -> None:
    """The table's c(0.05, 0.25, 1) = 2.3832 (published 2.3860); a fresh simulation agrees within
    3 standard errors (about 0.017 each with 10^4 paths); a finite horizon lowers it; a level
    off the table is simulated, and monitor_regression names the way there."""
    table = tightscan.monitoring_critical_value(0.05, 0.25)
    assert table == pytest.approx(2.3832, abs=1e-4)
    simulated = tightscan.monitoring_critical_value(0.05, 0.25, simulate=True, seed=3)
    assert abs(simulated - table) < 0.05
    assert tightscan.monitoring_critical_value(0.05, 0.25, simulate=True, seed=3, horizon_ratio=4.0) < simulated - 0.05
    off = tightscan.monitoring_critical_value(0.03, 0.25, simulate=True, seed=3)
    assert table < off < tightscan.monitoring_critical_value(0.025, 0.25)
    with pytest.raises(tightscan.InvalidParameterError) as err:
        tightscan.monitor_regression([float(i % 3) for i in range(60)], alpha=0.03)
    assert err.value.parameter == "alpha" and "monitoring_critical_value" in str(err.value)
    m = tightscan.monitor_regression([float(i % 3) for i in range(60)], alpha=0.03, critical_value=off)
    assert m.critical_value == off
    with pytest.raises(tightscan.InvalidParameterError) as err:
        tightscan.monitoring_critical_value(0.05, 0.25, horizon_ratio=2.0)
    assert err.value.parameter == "horizon_ratio"
