"""tightscan.plot (issue 14): the figures carry what the engine found, and only that.

Artists are found by their ``gid`` (stable names set by tightscan.plot), so the tests do not
depend on colours or label wording."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pytest

import tightscan
from tightscan.exceptions import DataFileError, InvalidParameterError, SchemaError

plot = pytest.importorskip("tightscan.plot", reason="tightscan.plot needs matplotlib")


@pytest.fixture(scope="module")
def scanned() -> tuple[pa.Table, pa.Table]:
    curves, _ = tightscan.simulate(40, seed=11, with_clamp_force=True, with_yield=True)
    return curves, tightscan.detect_batch(curves, passthrough=["strategy"])


def _ids(results: pa.Table, changed: bool) -> list[int]:
    mask = pc.fill_null(results.column("change_detected"), not changed)
    rows = results.filter(mask if changed else pc.invert(mask))
    return [i for i, s in zip(rows.column("tightening_id").to_pylist(), rows.column("status").to_pylist()) if s == "ok"]


def _gids(fig: Any) -> set[str]:
    out: set[str] = set()
    for ax in fig.axes:
        for artist in [*ax.get_lines(), *ax.patches, *ax.collections]:
            if artist.get_gid():
                out.add(artist.get_gid())
    return out


def test_import_tightscan_does_not_import_matplotlib() -> None:
    code = "import sys, tightscan; assert 'matplotlib' not in sys.modules, 'matplotlib imported'"
    subprocess.run([sys.executable, "-c", code], check=True)


def test_change_row_gets_onset_and_detector_markers(scanned: tuple[pa.Table, pa.Table]) -> None:
    curves, results = scanned
    tid = _ids(results, changed=True)[0]
    row = plot.result_row(results, tid)
    fig = plot.plot_tightening(curves, results, tid)
    gids = _gids(fig)
    assert {"torque", "elastic_line", "change_onset", "change_onset_marker", "torque_rate", "clamp_force"} <= gids
    assert {"phase:rundown", "phase:alignment", "phase:elastic window"} <= gids
    fired = row["detectors_fired"].split(",")
    assert fired and {f"detector:{d}" for d in fired} <= gids
    onset = next(line for line in fig.axes[0].get_lines() if line.get_gid() == "change_onset")
    assert onset.get_xdata()[0] == pytest.approx(row["change_angle"])
    # the legend names the detectors that fired
    legend = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert any(all(d in text for d in fired) for text in legend if text.startswith("change onset"))
    assert fig.axes[0].get_xlabel() == "angle [deg]"
    assert len(fig.axes) == 3  # torque, torque rate, clamp force


def test_clean_row_gets_no_change_marker(scanned: tuple[pa.Table, pa.Table]) -> None:
    curves, results = scanned
    tid = _ids(results, changed=False)[0]
    gids = _gids(plot.plot_tightening(curves, results, tid))
    assert "elastic_line" in gids and "torque" in gids
    assert not {g for g in gids if g.startswith("change_onset") or g.startswith("detector:")}


def test_yield_zone_shaded_where_the_curve_yields(scanned: tuple[pa.Table, pa.Table]) -> None:
    curves, results = scanned
    yielded = results.filter(pc.is_valid(results.column("yield_angle"))).column("tightening_id").to_pylist()
    assert yielded, "with_yield=True should give curves that yield"
    assert "phase:yield" in _gids(plot.plot_tightening(curves, results, yielded[0]))


def test_long_layout_reads_the_same_tightening(scanned: tuple[pa.Table, pa.Table]) -> None:
    curves, results = scanned
    tid = _ids(results, changed=True)[0]
    nested = plot.tightening_curve(curves, tid)
    rows = curves.filter(pc.equal(curves.column("tightening_id"), tid))
    n = len(rows.column("angle")[0])
    long = pa.table({
        "tightening_id": pa.array([tid] * n + [tid + 1000] * 3, pa.int64()),
        "angle": pa.array(list(rows.column("angle")[0].as_py()) + [0.0, 1.0, 2.0], pa.float32()),
        "torque": pa.array(list(rows.column("torque")[0].as_py()) + [0.0, 0.1, 0.2], pa.float32()),
    })
    again = plot.tightening_curve(long, tid)
    np.testing.assert_array_equal(again["angle"], nested["angle"])
    np.testing.assert_array_equal(again["torque"], nested["torque"])
    assert "change_onset" in _gids(plot.plot_tightening(long, results, tid))


def test_into_a_given_axes(scanned: tuple[pa.Table, pa.Table]) -> None:
    from matplotlib.figure import Figure

    curves, results = scanned
    fig = Figure()
    ax = fig.subfigures(1, 2)[1].add_subplot()
    assert plot.plot_tightening(curves, results, 0, ax=ax) is fig


@pytest.mark.parametrize("bad", [123456, "x"])
def test_unknown_id_is_a_clear_error(scanned: tuple[pa.Table, pa.Table], bad: object) -> None:
    curves, results = scanned
    with pytest.raises(InvalidParameterError, match=f"tightening_id {bad!r}") as err:
        plot.plot_tightening(curves, results, bad)
    assert err.value.parameter == "tightening_id"
    with pytest.raises(InvalidParameterError, match="not in the results"):
        plot.plot_detectors(curves, results.filter(pc.not_equal(results.column("tightening_id"), 3)), 3)


def test_missing_channel_names_it(scanned: tuple[pa.Table, pa.Table]) -> None:
    curves, results = scanned
    with pytest.raises(SchemaError, match="'torque'"):
        plot.plot_tightening(curves.drop_columns(["torque"]), results, 0)


def test_detector_charts(scanned: tuple[pa.Table, pa.Table]) -> None:
    """The detector panels draw the engine's traces against the limits the row reports."""
    curves, results = scanned
    tid = _ids(results, changed=True)[0]
    row = plot.result_row(results, tid)
    fig = plot.plot_detectors(curves, results, tid)
    gids = _gids(fig)
    assert {"cusum:upper", "cusum:lower", "cusum:threshold", "break:lr", "break:critical_value", "break:split", "kde:before", "kde:after", "change_onset"} <= gids

    def line(gid: str) -> Any:
        return next(x for ax in fig.axes for x in ax.get_lines() if x.get_gid() == gid)

    assert line("cusum:threshold").get_ydata()[0] == pytest.approx(row["cusum_threshold"])
    assert line("break:critical_value").get_ydata()[0] == pytest.approx(row["break_critical_value"])
    assert max(line("break:lr").get_ydata()) == pytest.approx(row["break_statistic"])
    top = np.maximum(line("cusum:upper").get_ydata(), line("cusum:lower").get_ydata())
    assert bool((top > row["cusum_threshold"]).any()) == bool(row["cusum_alarm"])
    assert line("change_onset").get_xdata()[0] == pytest.approx(row["change_angle"])
    assert all(d in fig.get_suptitle() for d in row["detectors_fired"].split(","))


def test_sequence_control_chart_marks_the_shifted_group() -> None:
    rng = np.random.default_rng(4)
    n = 40
    stations, order, rate = [], [], []
    for s in ("a", "b", "c", "d", "e"):
        values = 1.0 + 0.01 * rng.standard_normal(n)
        if s == "c":
            values[25:] += 0.1
        stations += [s] * n
        order += list(range(n))
        rate += values.tolist()
    table = pa.table({"station": stations, "n": order, "torque_rate": rate})
    fig = plot.plot_sequence(table, by="station", order_by="n", feature="torque_rate")
    visible = [ax for ax in fig.axes if ax.get_visible()]
    assert len(visible) == 5  # small multiples, no CUSUM row for five groups
    first = {ax.get_title().split(" ")[0]: [ln.get_xdata()[0] for ln in ax.get_lines() if ln.get_gid() == "first_alarm"] for ax in visible}
    assert first["station=c"] and 25 <= first["station=c"][0] <= 30
    assert visible[0].get_title().startswith("station=c")  # earliest alarm first
    # one group: the chart gets its CUSUM row with the threshold
    one = plot.plot_sequence(table.filter(pc.equal(table.column("station"), "c")), order_by="n")
    assert {"values", "centre", "limit", "cusum", "cusum_threshold", "first_alarm"} <= _gids(one)


def test_sequence_default_feature_is_the_friction_proxy(scanned: tuple[pa.Table, pa.Table]) -> None:
    _, results = scanned
    fig = plot.plot_sequence(results, by="strategy", order_by="tightening_id")
    assert fig.axes[0].get_ylabel() == "mu_tot"
    no_mu = results.drop_columns(["mu_tot"])
    assert plot.plot_sequence(no_mu, order_by="tightening_id").axes[0].get_ylabel() == "torque_rate"


SPECTRUM = {
    "model": "declared + runout",
    "effects": [],
    "spectrum": {
        "peaks": [
            {"domain": "angle", "period_deg": 360.0, "frequency": 1 / 360, "power_ratio": 40.0, "p_value": 1e-9, "explained_by": "runout"},
            {"domain": "angle", "period_deg": 12.0, "frequency": 1 / 12, "power_ratio": 6.0, "p_value": 1e-4, "explained_by": None},
        ],
        "axes": {"angle": {}, "time": {}},
    },
}


def test_spectrum_from_the_json_document(tmp_path: Path) -> None:
    path = tmp_path / "diag.json"
    path.write_text(json.dumps(SPECTRUM))
    fig = plot.plot_spectrum(path)
    assert len(fig.axes) == 2  # one panel per axis searched
    peaks = [ln for ln in fig.axes[0].get_lines() if ln.get_gid() == "peak"]
    assert sorted(ln.get_xdata()[0] for ln in peaks) == [12.0, 360.0]
    notes = [t.get_text() for t in fig.axes[0].texts]
    assert any("runout" in t for t in notes) and any("unexplained" in t for t in notes)
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(DataFileError, match="bad.json"):
        plot.plot_spectrum(bad)


def test_detection_quality_plots_whatever_series_exist(tmp_path: Path) -> None:
    record = {
        "recall_vs_magnitude": {
            "edges": [0.03, 0.06, 0.09, 0.12],
            "same_curves": {"ours (rule)": [0.2, 0.6, None], "binseg (matched)": [0.1, 0.4, 0.8]},
            "ours_all_curves": {"ours (rule)": [0.3, 0.7, 0.95]},
            "by_strategy": {"CST": {"ours (rule)": [0.1, 0.5, 0.9]}},  # a key a later bench may add
        },
        "something_else": 1,
    }
    path = tmp_path / "dq.json"
    path.write_text(json.dumps(record))
    fig = plot.plot_detection_quality(path)
    assert len(fig.axes) == 3
    line = next(ln for ln in fig.axes[0].get_lines() if ln.get_gid() == "recall:binseg (matched)")
    np.testing.assert_allclose(line.get_xdata(), [4.5, 7.5, 10.5])
    np.testing.assert_allclose(line.get_ydata(), [10, 40, 80])
    with pytest.raises(SchemaError, match="recall_vs_magnitude"):
        plot.plot_detection_quality({"goals": {}})


def test_real_curves_draw_without_warnings(rexroth_dir: Path) -> None:
    """Measured Rexroth curves (aborted runs, repeated samples, no clamp force): every row draws,
    with no warning (filterwarnings = error), whatever its status."""
    files = sorted((rexroth_dir / "runs").glob("*.json"))[::250]
    real = tightscan.read_rexroth(files, progress=False)
    results = tightscan.detect_batch(real)
    statuses = {s.split(":")[0] for s in results.column("status").to_pylist()}
    assert "ok" in statuses and len(statuses) > 1  # clean and malformed rows both drawn
    for tid, status in zip(results.column("tightening_id").to_pylist(), results.column("status").to_pylist()):
        fig = plot.plot_tightening(real, results, tid)
        assert "clamp_force" not in _gids(fig) and len(fig.axes) == 2
        if status == "ok":
            plot.plot_detectors(real, results, tid)


def test_polars_and_pandas_frames_draw_the_same(scanned: tuple[pa.Table, pa.Table]) -> None:
    pl = pytest.importorskip("polars")
    curves, results = scanned
    tid = _ids(results, changed=True)[0]
    arrow = plot.tightening_curve(curves, tid)
    for frame in (pl.from_arrow(curves), curves.to_pandas()):
        again = plot.tightening_curve(frame, tid)
        np.testing.assert_array_equal(again["torque"], arrow["torque"])
    assert "change_onset" in _gids(plot.plot_tightening(pl.from_arrow(curves), pl.from_arrow(results), tid))
