"""tightscan.detector_traces (issue 14): the per-sample statistics behind a result row are the
engine's own, so they cross their limits exactly where the row says each detector fired.

Curves: the built-in simulator with faults of both signs (friction up and down) and clean
curves, fixed seeds; the KDE test on in one configuration, so that all four traces run."""

from __future__ import annotations

from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pytest

import tightscan
from tightscan.exceptions import InvalidParameterError

CONFIG: dict[str, Any] = {"kde": True, "kde_permutations": 199}


@pytest.fixture(scope="module")
def simulated() -> tuple[pa.Table, pa.Table, pa.Table]:
    curves, truth = tightscan.simulate(36, seed=21, fault_fraction=0.6, magnitude_range=(0.05, 0.3))
    return curves, truth, tightscan.detect_batch(curves, CONFIG)


def _same_row(a: dict[str, Any], b: dict[str, Any]) -> bool:
    """Rows equal value for value (NaN equal to NaN)."""
    def same(x: Any, y: Any) -> bool:
        return x == y or (isinstance(x, float) and isinstance(y, float) and np.isnan(x) and np.isnan(y))
    return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)


def _chosen(truth: pa.Table, results: pa.Table) -> list[int]:
    """Ok tightenings: clean ones, friction rises and friction falls, a handful of each."""
    rows = pa.Table.from_pydict({
        "id": results.column("tightening_id"),
        "status": results.column("status"),
        "magnitude": pc.fill_null(truth.column("magnitude"), 0.0),
        "has_change": truth.column("has_change"),
    }).to_pylist()
    ok = [r for r in rows if r["status"] == "ok"]
    clean = [r["id"] for r in ok if not r["has_change"]][:5]
    up = [r["id"] for r in ok if r["has_change"] and r["magnitude"] > 0][:5]
    down = [r["id"] for r in ok if r["has_change"] and r["magnitude"] < 0][:5]
    assert len(clean) >= 3 and len(up) >= 3 and len(down) >= 3, (clean, up, down)
    return clean + up + down


def test_traces_cross_their_limits_exactly_when_the_detectors_fired(simulated: tuple[pa.Table, pa.Table, pa.Table]) -> None:
    curves, truth, results = simulated
    fired = {"cusum": 0, "break": 0, "l1": 0, "kde_changes": 0}
    silent = {"cusum": 0, "break": 0}
    for tid in _chosen(truth, results):
        row = results.filter(pc.equal(results.column("tightening_id"), tid)).to_pylist()[0]
        t = tightscan.detector_traces(curves, tid, CONFIG)
        # the trace's row is the batch's row, column for column
        assert _same_row(t.result, row), tid
        assert t.breaks is not None and t.kde is not None, tid

        if t.cusum is None:  # a window too short for its blocks: the row's CUSUM columns are null
            assert row["cusum_alarm"] is None and row["cusum_max_statistic"] is None, tid
        else:
            top = np.maximum(t.cusum.upper, t.cusum.lower)
            assert bool((top > t.cusum.threshold).any()) == row["cusum_alarm"], tid
            assert t.cusum.threshold == row["cusum_threshold"]
            assert float(top.max()) == row["cusum_max_statistic"]
            if row["cusum_alarm"]:
                first = int(np.argmax(top > t.cusum.threshold))
                assert t.cusum.angle[first] == row["cusum_alarm_angle"]
                side = "increase" if t.cusum.upper[first] > t.cusum.threshold else "decrease"
                assert side == row["cusum_side"], tid

        lr = t.breaks.lr
        assert float(lr.max()) == pytest.approx(row["break_statistic"], rel=1e-12)
        assert t.breaks.critical_value == row["break_critical_value"]
        assert bool(lr.max() > t.breaks.decision_value) == t.breaks.significant, tid
        assert (t.breaks.scan_alarm or t.breaks.tail_alarm or t.breaks.head_alarm or t.breaks.episode_alarm) == row["break_alarm"], tid
        if t.breaks.scan_alarm:
            # the profile's maximum is the break onset the row reports
            assert t.breaks.angle[int(np.argmax(lr))] == row["break_change_angle"], tid

        if t.l1 is not None:
            crossed = np.nonzero(t.l1.statistic >= t.l1.boundary)[0]
            assert (t.l1.angle[crossed[0]] if len(crossed) else None) == row["l1_alarm_angle"], tid

        assert t.kde.tested and len(t.kde.grid) == len(t.kde.before) == len(t.kde.after)
        for density in (t.kde.before, t.kde.after):  # densities: non-negative, area about 1
            assert density.min() >= 0 and np.trapezoid(density, t.kde.grid) == pytest.approx(1.0, abs=0.02)

        for det in ("cusum", "break"):
            if row[f"{det}_alarm"]:
                fired[det] += 1
            elif row[f"{det}_alarm"] is not None:
                silent[det] += 1
        fired["l1"] += bool(row["l1_alarm"])
        fired["kde_changes"] += bool(row["change_detected"])
    # both outcomes of both deciding detectors were checked
    assert min(fired["cusum"], fired["break"], silent["cusum"], silent["break"]) >= 1, (fired, silent)


def test_l1_boundary_is_the_gamma_boundary(simulated: tuple[pa.Table, pa.Table, pa.Table]) -> None:
    curves, truth, results = simulated
    tid = _chosen(truth, results)[0]
    l1 = tightscan.detector_traces(curves, tid, CONFIG).l1
    assert l1 is not None
    m, c, gamma = l1.training, l1.critical_value, l1.gamma
    k = np.arange(1, len(l1.boundary) + 1, dtype=float)
    g = c * np.sqrt(m) * (1 + k / m) * (k / (m + k)) ** gamma
    np.testing.assert_allclose(l1.boundary, g, rtol=1e-12)
    assert gamma == 0.25 and m >= 10
    assert np.all(np.diff(l1.angle) > 0)


def test_default_config_and_long_layout_give_the_same_traces(simulated: tuple[pa.Table, pa.Table, pa.Table]) -> None:
    curves, _, _ = simulated
    small = curves.slice(0, 4)
    results = tightscan.detect_batch(small)
    tid = 2
    nested = tightscan.detector_traces(small, tid)
    assert nested.kde is not None and not nested.kde.tested  # the KDE test is off by default
    assert _same_row(nested.result, results.filter(pc.equal(results.column("tightening_id"), tid)).to_pylist()[0])
    # the same tightening in the long layout (one row per sample)
    one = small.filter(pc.equal(small.column("tightening_id"), tid))
    n = len(one.column("angle")[0])
    long = pa.table({
        "tightening_id": pa.array([tid] * n, pa.int64()),
        "angle": one.column("angle").combine_chunks().flatten(),
        "torque": one.column("torque").combine_chunks().flatten(),
    })
    again = tightscan.detector_traces(long, tid)
    assert again.status == nested.status
    assert again.cusum is not None and nested.cusum is not None
    np.testing.assert_array_equal(again.cusum.upper, nested.cusum.upper)
    np.testing.assert_array_equal(again.breaks.lr if again.breaks else [], nested.breaks.lr if nested.breaks else [])


def test_a_malformed_tightening_gives_its_status_and_no_traces() -> None:
    angle = [float(i) for i in range(200)]
    torque = [0.0 if i < 50 else 0.3 * (i - 50) for i in range(200)]
    table = pa.table({
        "tightening_id": [1, 2, 3],
        "angle": [angle, angle[:150], angle],
        "torque": [torque, torque, [float("nan")] * 200],
    })
    for tid, status in ((2, "length_mismatch"), (3, "non_finite")):
        t = tightscan.detector_traces(table, tid)
        assert t.status.startswith(status), t.status
        assert (t.cusum, t.l1, t.breaks, t.kde) == (None, None, None, None)
    with pytest.raises(InvalidParameterError, match="tightening_id 9"):
        tightscan.detector_traces(table, 9)
    with pytest.raises(InvalidParameterError, match="alpha"):
        tightscan.detector_traces(table, 1, {"alpha": 2.0})


def test_detector_figure_draws_the_traces(simulated: tuple[pa.Table, pa.Table, pa.Table]) -> None:
    plot = pytest.importorskip("tightscan.plot", reason="tightscan.plot needs matplotlib")
    curves, truth, results = simulated
    changed = [i for i in _chosen(truth, results) if results.filter(pc.equal(results.column("tightening_id"), i)).column("change_detected")[0].as_py()]
    tid = changed[0]
    row = plot.result_row(results, tid)
    # no config given: the one the results record (kde on) is used
    fig = plot.plot_detectors(curves, results, tid)
    gids = {a.get_gid() for ax in fig.axes for a in [*ax.get_lines(), *ax.collections] if a.get_gid()}
    assert {"cusum:upper", "cusum:lower", "cusum:threshold", "l1:statistic", "l1:boundary", "break:lr", "break:critical_value", "break:split", "kde:before", "kde:after", "change_onset"} <= gids
    ax_cusum = fig.axes[0]
    threshold = next(line for line in ax_cusum.get_lines() if line.get_gid() == "cusum:threshold")
    assert threshold.get_ydata()[0] == pytest.approx(row["cusum_threshold"])
    onset = next(line for line in fig.axes[2].get_lines() if line.get_gid() == "change_onset")
    assert onset.get_xdata()[0] == pytest.approx(row["change_angle"])
    ax_kde = fig.axes[3]
    assert "KDE test p" in ax_kde.get_title(loc="right")
    assert "another config" not in fig.get_suptitle()
